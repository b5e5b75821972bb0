"""`jthermo tune` on the virtual printer at its own scale: every family at N zones with the
CLI's defaults, each run in its own process under a watchdog.

Per run: exit status, wall time and CPU s of the child (user+sys), the improvement below the
lambda PI and below the best classical design on the held-out seed, and the Ms guard (the
chosen loop's peak sensitivity against its bound). `cold`: a fresh compilation cache;
`warm`: the same command again on that cache.

`--ab`: the two ways to keep `tune_report`'s two threads off a deadlock, compared on one
configuration: its threads with LAPACK one matrix at a time (`runtime.one_matrix_at_a_time`,
as shipped) against no second thread (its work run in turn on the main thread) with the
batched kernels; each cold then warm, in its own process.

Usage:
    .venv/bin/python experiments/printer_scale.py [--zones 16,9,19]
        [--families pi,pi_ff,lqg,lqg_ff] [--warm] [--limit 1500]
        [--ab [--ab-steps 10]] [--zones ''] (`--zones ''`: the A/B runs alone) [--resume]
Writes `experiments/results/printer_scale.md` (overwritten after every run, so a run cut short
keeps what it measured).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "results" / "printer_scale.md"
JTHERMO = [sys.executable, "-m", "jthermo.cli"]

AB_CHILD = r"""
import json, os, sys, time
from concurrent.futures import Future
import jax
jax.config.update("jax_enable_x64", True)
from jthermo import runtime
runtime.enable_cache(); runtime.unroll_threefry()
import jthermo.tune.report as R
mode, steps = sys.argv[1], int(sys.argv[2])
if mode == "serial":            # no second thread, batched LAPACK kernels
    R.one_matrix_at_a_time = lambda: False

    class InOrder:
        def __init__(self, *a, **k): pass
        def __enter__(self): return self
        def __exit__(self, *a): pass
        def submit(self, fn, *a, **k):
            f = Future(); f.set_result(fn(*a, **k)); return f

    R.ThreadPoolExecutor = InOrder
t0, c0 = time.time(), time.process_time()
rep = R.tune_report("lqg", plant="printer", zones=16, steps=steps, rollouts=16, seed=11, lr=0.1)
print(json.dumps({"wall": time.time() - t0, "cpu": time.process_time() - c0,
                  "improvement": rep["improvement_percent"]}))
"""


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(argv, env, limit):
    c0, t0 = _children_cpu(), time.perf_counter()
    try:
        p = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=limit, cwd=ROOT)
        rc, err = p.returncode, p.stderr
    except subprocess.TimeoutExpired as exc:
        rc, err = "timeout", (exc.stderr or b"").decode() if isinstance(exc.stderr, bytes) \
            else (exc.stderr or "")
    last = next((ln for ln in reversed(err.strip().splitlines()) if ln.strip()), "")
    return rc, time.perf_counter() - t0, _children_cpu() - c0, last, p.stdout if rc == 0 else ""


def tune_row(family, zones, cache, limit, label):
    js = Path(tempfile.mkdtemp(prefix="jthermo-scale-")) / "t.json"
    env = {**os.environ, "JTHERMO_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
    argv = JTHERMO + ["tune", "--controller", family, "--plant", "printer", "--zones",
                      str(zones), "--seed", "11", "--json", str(js), "--quiet"]
    rc, wall, cpu, last, _ = _run(argv, env, limit)
    row = {"family": family, "zones": zones, "cache": label, "rc": rc, "wall_s": wall,
           "cpu_s": cpu, "stderr": last}
    if rc == 0 and js.exists():
        r = json.loads(js.read_text())
        ms = r.get("ms_constraint") or {}
        row.update(vs_lambda=r.get("improvement_percent"),
                   vs_best=r.get("improvement_vs_best_classical_percent"),
                   best=r.get("best_classical"), ms=ms.get("chosen_ms"),
                   ms_max=ms.get("ms_max"), ms_ok=ms.get("satisfied"),
                   steps=r.get("steps"))
    return row


def _f(v, nd=1):
    return "-" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))


def render(rows, ab, load) -> str:
    zones = ", ".join(str(z) for z in sorted({r["zones"] for r in rows})) or "no"
    lines = [f"# `jthermo tune` on the virtual printer at its scale ({zones} zones measured)", "",
             "Measured on a shared, loaded 2-core machine (other jobs ran meanwhile; 1-minute "
             f"load average {load}): wall times are upper bounds, CPU s (user+sys of the child) "
             "the steadier figure. Seed 11, CLI defaults otherwise; `cold` on an empty "
             "compilation cache, `warm` on that cache again.", "",
             "Reproduce: `python experiments/printer_scale.py --zones 16,9,19 --warm` "
             "(and `--ab` for the last table).", "",
             "| family | zones | cache | exit | wall s | CPU s | below lambda PI % | "
             "below best classical % (best) | Ms (bound, ok) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ms = "-" if r.get("ms") is None else \
            f"{r['ms']:.2f} ({_f(r.get('ms_max'), 1)}, {r.get('ms_ok')})"
        lines.append(f"| {r['family']} | {r['zones']} | {r['cache']} | {r['rc']} | "
                     f"{_f(r['wall_s'], 0)} | {_f(r['cpu_s'], 0)} | {_f(r.get('vs_lambda'))} | "
                     f"{_f(r.get('vs_best'))} ({r.get('best', '-')}) | {ms} |")
    bad = [r for r in rows if r["rc"] != 0]
    for r in bad:
        lines.append(f"\n{r['family']} at {r['zones']} zones ({r['cache']}): exit {r['rc']}, "
                     f"last stderr line: `{r['stderr'][:300]}`")
    if ab:
        lines += ["", "## Two threads with LAPACK one matrix at a time, or one thread", "",
                  "`tune_report('lqg', zones=16, rollouts=16, steps=10, seed=11, lr=0.1)` (`--ab-steps`) in its "
                  "own process: `threads` as shipped (`runtime.one_matrix_at_a_time`), `serial` "
                  "the second thread's work run in turn on the main thread with the batched "
                  "kernels. Same improvement in every run (bit-equal reports).", "",
                  "| variant | cache | wall s | CPU s | below lambda PI % |", "|---|---|---|---|---|"]
        for r in ab:
            lines.append(f"| {r['variant']} | {r['cache']} | {_f(r.get('wall'), 0)} | "
                         f"{_f(r.get('cpu'), 0)} | {_f(r.get('improvement'), 3)} |")
    lines += ["", f"<!-- rows (read back by --resume): {json.dumps({'rows': rows, 'ab': ab})} -->"]
    return "\n".join(lines) + "\n"


def _resumed() -> tuple[list, list]:
    """The rows and A/B runs recorded in the results file (`--resume`), else empty lists."""
    try:
        text = OUT.read_text()
        blob = text.rsplit("<!-- rows (read back by --resume): ", 1)[1].rsplit(" -->", 1)[0]
        got = json.loads(blob)
        return [r for r in got["rows"] if r.get("rc") == 0], got["ab"]
    except (OSError, IndexError, ValueError, KeyError):
        return [], []


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zones", default="16,9,19")
    ap.add_argument("--families", default="pi,pi_ff,lqg,lqg_ff")
    ap.add_argument("--warm", action="store_true")
    ap.add_argument("--limit", type=float, default=1500.0, help="seconds per run")
    ap.add_argument("--ab", action="store_true")
    ap.add_argument("--ab-steps", type=int, default=10)
    ap.add_argument("--resume", action="store_true",
                    help="keep the finished runs of the results file, run only the others")
    a = ap.parse_args()
    rows, ab = _resumed() if a.resume else ([], [])
    done = {(r["family"], r["zones"], r["cache"]) for r in rows}
    load = lambda: f"{os.getloadavg()[0]:.1f}"   # noqa: E731
    loads = [str(r.get("load", "?")) for r in rows]
    for zones in (int(z) for z in a.zones.split(",") if z):
        for family in a.families.split(","):
            cache = Path(tempfile.mkdtemp(prefix="jthermo-scale-cache-"))
            for label in ("cold", "warm") if a.warm else ("cold",):
                if (family, zones, label) in done:
                    continue
                rows.append({**tune_row(family, zones, cache, a.limit, label), "load": load()})
                loads.append(load())
                OUT.write_text(render(rows, ab, " ".join(loads)))
                print(json.dumps(rows[-1]), flush=True)
    if a.ab and not ab:
        for variant in ("serial", "threads"):
            cache = Path(tempfile.mkdtemp(prefix="jthermo-ab-"))
            env = {**os.environ, "JTHERMO_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
            for label in ("cold", "warm"):
                rc, *_, out = _run([sys.executable, "-c", AB_CHILD, variant, str(a.ab_steps)],
                                   env, a.limit)
                rec = json.loads(out.strip().splitlines()[-1]) if rc == 0 else {}
                ab.append({"variant": variant, "cache": label, **rec})
                loads.append(load())
                OUT.write_text(render(rows, ab, " ".join(loads)))


if __name__ == "__main__":
    main()
