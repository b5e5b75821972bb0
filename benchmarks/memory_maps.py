"""Memory maps and compiled programs of one long-lived process that fits records of many lengths.

Every XLA CPU executable keeps memory maps of its code, and Linux allows a process
`vm.max_map_count` of them (65,530 by default): a process that compiles a program for every
record length it meets dies in LLVM ("Unable to allocate section memory") after a few hundred
fits. This script fits, in one process and through the public API, virtual-printer records of
`--zones` zones and lengths 600, 637, 674, ... s (`--step`), and after each fit prints the
process's memory maps (lines of `/proc/self/maps`), the programs compiled so far (JAX's
backend-compile events) and the caches the library's guard cleared (`runtime.guard_info`).

    python benchmarks/memory_maps.py                       # oe then every family, 8 fits each
    python benchmarks/memory_maps.py --families oe --fits 60 --zones 2,3,4 --source generate

`--source generate` makes each record with `printer.generate` (itself a compiled simulation
of the record's length, as a user's script would); `crop` (default) cuts every record from
one long record, so the figures are those of `fit` alone. Writes
`benchmarks/results/memory_maps.md` (overwritten when rerun).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jthermo  # noqa: E402
from jthermo import programs, runtime  # noqa: E402
from jthermo.data import crop  # noqa: E402
from jthermo.printer import make_printer  # noqa: E402
from jthermo.printer.runs import generate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
FAMILIES = ("oe", "arx", "armax", "bj", "ss", "greybox")


COMPILED = [0]


def _on_event(event: str, duration: float, **_) -> None:
    if event == "/jax/core/compile/backend_compile_duration":
        COMPILED[0] += 1


def guard_info() -> dict:
    """The library's guard figures (none where this jthermo has no guard)."""
    info = getattr(runtime, "guard_info", None)
    return info() if info else {"clears": 0, "bound": None}


def maps() -> int:
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


def records(zones: list[int], n: int, start: int, step: int, source: str):
    """`n` records cycling over `zones`, lengths start, start + step, ... samples (ts = 1 s)."""
    longs = {}
    for i in range(n):
        z = zones[i % len(zones)]
        length = start + step * i
        pr = make_printer(z)
        if source == "generate":
            yield z, length, generate(pr, duration=float(length), seed=i)
            continue
        if z not in longs:
            longs[z] = generate(pr, duration=float(start + step * n + 10), seed=1)
        yield z, length, crop(longs[z], 0, int(round(length / pr.ts)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="oe," + ",".join(FAMILIES[1:]))
    ap.add_argument("--fits", type=int, default=8, help="fits per family")
    ap.add_argument("--zones", default="2")
    ap.add_argument("--start", type=int, default=600)
    ap.add_argument("--step", type=int, default=37)
    ap.add_argument("--source", choices=("crop", "generate"), default="crop")
    ap.add_argument("--bound", type=int, default=None,
                    help="the guard's bound on memory maps (default programs.MAP_BOUND)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "memory_maps.md"))
    a = ap.parse_args(argv)
    families = [f for f in a.families.split(",") if f]
    zones = [int(z) for z in a.zones.split(",")]
    if a.bound is not None:
        programs.MAP_BOUND = a.bound
    jax.monitoring.register_event_duration_secs_listener(_on_event)
    shown = list(argv if argv is not None else sys.argv[1:])
    if "--out" in shown:                      # where it was written is no part of the figures
        i = shown.index("--out")
        del shown[i:i + 2]
    rows, t_all = [], time.perf_counter()
    m0 = maps()
    print(f"start: {m0} maps", flush=True)
    for fam in families:
        first = None
        for i, (z, length, data) in enumerate(records(zones, a.fits, a.start, a.step, a.source)):
            t = time.perf_counter()
            jthermo.fit(data, fam)
            m, c = maps(), COMPILED[0]
            g = guard_info()
            rows.append((fam, i, z, length, m, c, g["clears"], time.perf_counter() - t))
            first = first or (m, c)
            print(f"{fam} fit {i + 1}: N={z} T={length} maps={m} compiled={c} "
                  f"clears={g['clears']} {rows[-1][-1]:.2f}s", flush=True)
    lines = ["# Memory maps of one process fitting records of many lengths", "",
             f"`python benchmarks/memory_maps.py {' '.join(shown)}`"
             f" (measured on a shared, loaded machine: load {os.getloadavg()[0]:.1f} at the end; "
             f"{time.perf_counter() - t_all:.0f} s in all). Records of N = {a.zones} zones, "
             f"lengths {a.start}, {a.start + a.step}, ... s, source `{a.source}`; Linux's limit "
             f"per process {Path('/proc/sys/vm/max_map_count').read_text().strip()} maps, the "
             f"guard's bound {guard_info()['bound']}; {m0} maps before the first fit.", "",
             "| family | fits | maps after fit 1 | maps at the end | max maps | maps / fit after fit 1 "
             "| programs compiled (end) | programs / fit after fit 1 | guard clears |",
             "|---|---|---|---|---|---|---|---|---|"]
    for fam in families:
        r = [x for x in rows if x[0] == fam]
        if not r:
            continue
        k = max(len(r) - 1, 1)
        lines.append(f"| {fam} | {len(r)} | {r[0][4]} | {r[-1][4]} | {max(x[4] for x in r)} | "
                     f"{(r[-1][4] - r[0][4]) / k:.0f} | {r[-1][5]} | {(r[-1][5] - r[0][5]) / k:.1f} | "
                     f"{r[-1][6]} |")
    lines += ["", "Per fit: family, fit, zones, length (s), maps, programs compiled so far, "
              "guard clears, seconds.", "", "```"]
    lines += [f"{f} {i + 1} N={z} T={t} maps={m} compiled={c} clears={g} {s:.2f}s"
              for f, i, z, t, m, c, g, s in rows]
    lines.append("```")
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines[:len(families) + 8]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
