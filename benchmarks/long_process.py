"""One long-lived process: fits of every family over records of many lengths and zone counts,
then diagnoses, through the public API alone (no `jax.clear_caches()` of its own).

Every XLA CPU executable keeps memory maps of its code and Linux allows a process
`vm.max_map_count` of them (65,530 by default): past it LLVM aborts the process. This script
makes `--fits` virtual-printer records with `printer.generate` (as a user's script would), of
1..`--max-zones` zones and lengths spread evenly over `--lengths` seconds (shuffled, every length
distinct), fits each with the next family of arx, armax, oe, bj, ss, greybox (automatic
orders, `jthermo.fit`), then diagnoses `--diagnoses` est/val pairs of printers with one effect
each (`jthermo.diagnose.diagnose`). A thread reads `/proc/self/maps` every `--every` seconds
throughout; after each job the script records the job's peak maps, the programs compiled so
far (JAX's compile and cache-load events, `runtime.compiled_programs`) and the guard's clears.

    python benchmarks/long_process.py                      # 300 fits + 20 diagnoses
    python benchmarks/long_process.py --fits 24 --diagnoses 2 --out /tmp/lp.md

Writes `benchmarks/results/long_process.md` (overwritten when rerun).
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import jthermo  # noqa: E402
from jthermo import runtime  # noqa: E402
from jthermo.diagnose import diagnose  # noqa: E402
from jthermo.printer import make_printer  # noqa: E402
from jthermo.printer.runs import generate  # noqa: E402

from common import cpu_seconds, load, results_path  # noqa: E402

FAMILIES = ("arx", "armax", "oe", "bj", "ss", "greybox")
#: the effects of the diagnosed printers, one per record, in turn
EFFECTS = ("radiative_loss", "lateral_conduction", "input_nonlinearity", "heater_lag")
#: the acceptance's bound on the process's memory maps
LIMIT = 30_000


class Maps:
    """The process's memory maps, read every `every` seconds by a thread: `peak()` since the
    last `reset()`, `overall` the run's peak."""

    def __init__(self, every: float):
        self.every, self.current, self.overall = every, self._read(), 0
        self._peak = self.current
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @staticmethod
    def _read() -> int:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)

    def _run(self):
        while not self._stop.wait(self.every):
            self.sample()

    def sample(self) -> int:
        n = self._read()
        self._peak = max(self._peak, n)
        self.overall = max(self.overall, n)
        return n

    def peak(self) -> int:
        self.sample()
        return self._peak

    def reset(self):
        self._peak = self.sample()

    def stop(self):
        self._stop.set()
        self._thread.join()


def plan(n: int, max_zones: int, lo: float, hi: float, seed: int):
    """`n` jobs `(family, zones, length in s)`: lengths distinct, evenly over [lo, hi], shuffled;
    zones and families cycling."""
    rng = np.random.default_rng(seed)
    lengths = np.round(np.linspace(lo, hi, n)).astype(int)
    rng.shuffle(lengths)
    return [(FAMILIES[i % len(FAMILIES)], 1 + (i // len(FAMILIES)) % max_zones, int(lengths[i]))
            for i in range(n)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fits", type=int, default=300)
    ap.add_argument("--diagnoses", type=int, default=20)
    ap.add_argument("--max-zones", type=int, default=6)
    ap.add_argument("--lengths", default="600,3600", help="lo,hi record length (s)")
    ap.add_argument("--diagnose-lengths", default="600,3600")
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--every", type=float, default=0.25, help="seconds between reads of the maps")
    ap.add_argument("--out", default=str(results_path(__file__)))
    a = ap.parse_args(argv)
    families = tuple(f for f in a.families.split(",") if f)
    lo, hi = (float(x) for x in a.lengths.split(","))
    dlo, dhi = (float(x) for x in a.diagnose_lengths.split(","))
    runtime.count_compiles()
    maps = Maps(a.every)
    m0, t0, c0 = maps.current, time.perf_counter(), cpu_seconds()
    print(f"start: {m0} maps, guard bound {runtime.guard_info()['bound']}", flush=True)
    rows, errors = [], []
    jobs = [(families[i % len(families)], z, T)
            for i, (_, z, T) in enumerate(plan(a.fits, a.max_zones, lo, hi, 1))]
    for i, (fam, z, T) in enumerate(jobs):
        maps.reset()
        t = time.perf_counter()
        try:
            data = generate(make_printer(z, seed=i), duration=float(T), seed=i)
            jthermo.fit(data, fam)
            err = ""
        except Exception as e:          # noqa: BLE001 - every failure is a figure here
            err = f"{type(e).__name__}: {e}"
            errors.append((f"fit {i + 1}", err))
        rows.append(("fit", i + 1, fam, z, T, maps.peak(), runtime.compiled_programs(),
                     runtime.guard_info()["clears"], time.perf_counter() - t, err))
        print("{} {} {} N={} T={} peak_maps={} compiled={} clears={} {:.1f}s {}".format(
            *rows[-1]), flush=True)
    djobs = plan(a.diagnoses, min(a.max_zones, 4), dlo, dhi, 2)
    for i, (_, z, T) in enumerate(djobs):
        maps.reset()
        t = time.perf_counter()
        eff = EFFECTS[i % len(EFFECTS)]
        z = max(z, 2) if eff == "lateral_conduction" else z
        try:
            pr = make_printer(z, effects=[eff], seed=100 + i)
            est = generate(pr, duration=float(T), seed=2 * i + 1)
            val = generate(pr, duration=float(T), seed=2 * i + 2)
            diagnose(est, val)
            err = ""
        except Exception as e:          # noqa: BLE001
            err = f"{type(e).__name__}: {e}"
            errors.append((f"diagnose {i + 1}", err))
        rows.append(("diagnose", i + 1, eff, z, T, maps.peak(), runtime.compiled_programs(),
                     runtime.guard_info()["clears"], time.perf_counter() - t, err))
        print("{} {} {} N={} T={} peak_maps={} compiled={} clears={} {:.1f}s {}".format(
            *rows[-1]), flush=True)
    maps.stop()
    wall, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    peak = max(maps.overall, max(r[5] for r in rows))
    shown = [x for x in (argv if argv is not None else sys.argv[1:])]
    if "--out" in shown:
        j = shown.index("--out")
        del shown[j:j + 2]
    ok = not errors and peak < LIMIT
    lines = ["# One long-lived process: fits of every family, then diagnoses", "",
             f"`python benchmarks/long_process.py {' '.join(shown)}`".replace(" `", "`"),
             "", f"Measured on a shared, loaded machine (load {load()} at the end): "
             f"{wall:.0f} s wall, {cpu:.0f} CPU s. {len(jobs)} fits ({', '.join(families)} in "
             f"turn; 1..{a.max_zones} zones; lengths {lo:g}..{hi:g} s, all distinct) then "
             f"{len(djobs)} diagnoses (1..{min(a.max_zones, 4)} zones, {dlo:g}..{dhi:g} s); "
             f"Linux's limit {Path('/proc/sys/vm/max_map_count').read_text().strip()} maps per "
             f"process, the guard's bound {runtime.guard_info()['bound']}.", "",
             f"- maps before the first job: {m0}; **peak maps {peak}** (read every {a.every:g} s "
             f"throughout; acceptance below {LIMIT:,}): {'met' if ok else 'NOT met'}",
             f"- programs compiled or loaded: {runtime.compiled_programs()} "
             f"({runtime.compiled_programs() / max(len(rows), 1):.1f} per job); guard clears: "
             f"{runtime.guard_info()['clears']}",
             f"- errors: {len(errors)}" + "".join(f"\n  - {w}: {e}" for w, e in errors), "",
             "| part | jobs | peak maps | programs at the end | programs / job | s / job |",
             "|---|---|---|---|---|---|"]
    for part in ("fit", "diagnose"):
        r = [x for x in rows if x[0] == part]
        if r:
            before = rows[rows.index(r[0]) - 1][6] if rows.index(r[0]) else 0
            lines.append(f"| {part} | {len(r)} | {max(x[5] for x in r)} | {r[-1][6]} | "
                         f"{(r[-1][6] - before) / len(r):.1f} | "
                         f"{sum(x[8] for x in r) / len(r):.1f} |")
    fams = sorted({x[2] for x in rows if x[0] == "fit"}, key=FAMILIES.index)
    if fams:
        lines += ["", "Programs compiled per fit by family (the count's increase over the "
                  "fit, mean over its fits):", "", "| family | fits | programs / fit |", "|---|---|---|"]
        for f in fams:
            inc = [rows[k][6] - (rows[k - 1][6] if k else 0) for k in range(len(rows))
                   if rows[k][0] == "fit" and rows[k][2] == f]
            lines.append(f"| {f} | {len(inc)} | {np.mean(inc):.1f} |")
    lines += ["", "Per job: part, number, family or effect, zones, length (s), peak maps over "
              "the job, programs so far, guard clears, seconds, error.", "", "```"]
    lines += ["{} {} {} N={} T={} peak_maps={} compiled={} clears={} {:.1f}s {}".format(*r).rstrip()
              for r in rows]
    lines.append("```")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines[:16]))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
