"""Threefry lowered with its rounds unrolled on the CPU (`runtime.unroll_threefry`, what the
`jthermo` command switches on) against JAX's default CPU lowering (a `while` loop over the
arrays): the run program of `jthermo simulate` (N = 16, B = 256, T = 3600 s by default)
compiled without a persistent cache, then run twice, in fresh processes taking turns.

Reports CPU seconds (user + system of the process, all threads) beside wall seconds and the
1-minute load (2 shared cores), and the reported MSE to every digit: the bits are the same.

    python benchmarks/simulate_threefry.py                  # 2 processes per lowering
    python benchmarks/simulate_threefry.py --rollouts 32 --duration 600 --repeats 1 --out -
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from common import finish, load

HERE = Path(__file__).resolve().parent

CHILD = """
import json, sys, time
import jax, equinox as eqx
jax.config.update("jax_enable_x64", True)
from jthermo import runtime
if {unrolled}:
    runtime.unroll_threefry()
from jthermo import closedloop as cl
from jthermo.closedloop import engine
from jthermo.control.design import design
from jthermo.printer import make_printer
from jthermo.tune import printer_model

p = make_printer({zones}, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
ctrl = design("pi_lambda", eqx.filter_jit(printer_model)(p))
key = jax.random.key(0)
rows = []
for _ in range(3):
    w, c = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(engine.scenario_metrics("tracking", p, ctrl, {duration}, key,
                                                         {rollouts}))
    rows.append((time.perf_counter() - w, time.process_time() - c))
print(json.dumps({{"rows": rows, "mse": float(out[0]["mse"])}}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=256)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--repeats", type=int, default=2, help="processes per lowering")
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_threefry.md"))
    args = ap.parse_args()
    env = {**os.environ, "JTHERMO_NO_CACHE": "1"}
    load0 = load()
    lines = ["# Threefry on the CPU: rolled (JAX's default) or unrolled (`jthermo`)", "",
             (f"`python benchmarks/simulate_threefry.py --zones {args.zones} --rollouts "
              f"{args.rollouts} --duration {args.duration:g} --repeats {args.repeats}`: the run "
              "program of `jthermo simulate --scenario tracking --controller pi` (scenarios and "
              "metrics in one compiled call), no persistent cache; first call = trace, compile "
              "and run; the run alone = the mean of two more calls. Fresh processes, the two "
              "lowerings taking turns."), "",
             "| lowering | first call wall s | first call CPU s | run wall s | run CPU s | load | mse |",
             "|---|---|---|---|---|---|---|"]
    for _ in range(args.repeats):
        for unrolled in (False, True):
            code = CHILD.format(unrolled=unrolled, zones=args.zones, duration=args.duration,
                                rollouts=args.rollouts)
            load_now = load()
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                                 capture_output=True, text=True)
            r = json.loads(res.stdout.strip().splitlines()[-1])
            (w0, c0), rest = r["rows"][0], r["rows"][1:]
            lines.append(f"| {'unrolled' if unrolled else 'rolled'} | {w0:.2f} | {c0:.2f} | "
                         f"{sum(w for w, _ in rest) / len(rest):.2f} | "
                         f"{sum(c for _, c in rest) / len(rest):.2f} | {load_now} | "
                         f"{r['mse']!r} |")
            print(lines[-1], f"({time.perf_counter() - t0:.0f} s)", flush=True)
    finish(lines, load0, args.out)


if __name__ == "__main__":
    sys.exit(main())
