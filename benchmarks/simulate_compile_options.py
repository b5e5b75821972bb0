"""XLA compile options of `jthermo simulate`'s run program: compile time against run time.

Each row is a fresh process with no compilation cache: it builds the N-zone printer, designs
lambda PI as the command does, then traces, compiles (with the row's options) and runs
`closedloop.engine.scenario_metrics` (the command's run program: scenarios drawn inside, noise
in the scan, lean metrics) three times. Reported per row, median over `--repeats` processes:
CPU s (user + system, all threads) and wall s of the compile and of one execution (the median
of the three), and the mse. A program compiled once per cache but run on every call pays its
run time on each warm call and its compile time once.

    python benchmarks/simulate_compile_options.py [--zones 16 --rollouts 256 --duration 3600]
    python benchmarks/simulate_compile_options.py --only "older CPU fusion emitters" \
        "older emitters, LLVM -O1" --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from common import load

HERE = Path(__file__).resolve().parent

OPTIONS = {"default": {}, "older CPU fusion emitters": {"xla_cpu_use_fusion_emitters": False},
           "older emitters, LLVM -O1": {"xla_cpu_use_fusion_emitters": False,
                                        "xla_backend_optimization_level": 1}}

CHILD = r"""
import json, sys, time
from jthermo import runtime
runtime.unroll_threefry()
import jax, equinox as eqx, numpy as np
jax.config.update("jax_enable_x64", True)
from jthermo import closedloop as cl
from jthermo.closedloop import engine
from jthermo.control.design import design
from jthermo.printer import make_printer
from jthermo.tune import printer_model
zones, B, dur, opts = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), json.loads(sys.argv[4])
plant = make_printer(zones, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
ctrl = design("pi_lambda", eqx.filter_jit(printer_model, compiler_options=runtime.ONE_SHOT)(plant))
key = jax.random.key(0)
args = ("tracking", plant, ctrl, dur, key, B)
def clock():
    return time.perf_counter(), time.process_time()
w, c = clock()
lowered = engine.scenario_metrics.lower(*args)
w1, c1 = clock()
compiled = lowered.compile(compiler_options=opts)
w2, c2 = clock()
runs = []
for _ in range(3):
    a, b = clock()
    out = jax.block_until_ready(compiled(*args))
    a2, b2 = clock()
    runs.append((a2 - a, b2 - b))
runs.sort(key=lambda r: r[1])
print(json.dumps({"lower_cpu": c1 - c, "compile_wall": w2 - w1, "compile_cpu": c2 - c1,
                  "run_wall": runs[1][0], "run_cpu": runs[1][1], "mse": float(out[0]["mse"])}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=256)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--only", nargs="+", choices=list(OPTIONS), default=list(OPTIONS),
                    help="option sets to run (default all)")
    args = ap.parse_args()
    import numpy as np

    env = dict(os.environ, JTHERMO_NO_CACHE="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    load0 = load()
    rows = {}
    for name in args.only:
        opts = OPTIONS[name]
        runs = []
        for _ in range(args.repeats):
            out = subprocess.run([sys.executable, "-c", CHILD, str(args.zones), str(args.rollouts),
                                  str(args.duration), json.dumps(opts)], env=env, check=True,
                                 capture_output=True, text=True).stdout
            runs.append(json.loads(out.strip().splitlines()[-1]))
            print(name, runs[-1], flush=True)
        rows[name] = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
    lines = [(f"# Compile options of the run program: N = {args.zones}, B = {args.rollouts}, "
              f"T = {args.duration:g} s"), "",
             (f"`python benchmarks/simulate_compile_options.py --zones {args.zones} --rollouts "
              f"{args.rollouts} --duration {args.duration:g} --repeats {args.repeats}"
              + ("" if args.only == list(OPTIONS) else " --only " + " ".join(
                  f'"{n}"' for n in args.only))
              + "`: a fresh "
              "process per repeat, no compilation cache; medians over the repeats (one execution: "
              "the median of three). 1-minute load "
              f"{load0} at the start, {load()} at the end (2 shared cores: wall s follow the "
              "load; CPU s are user + system of all threads)."), "",
             "| XLA options | compile CPU s | compile wall s | execute CPU s | execute wall s | mse |",
             "|---|---|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(f"| {name} `{OPTIONS[name]}` | {r['compile_cpu']:.2f} | {r['compile_wall']:.2f} | "
                     f"{r['run_cpu']:.2f} | {r['run_wall']:.2f} | {r['mse']!r} |")
    text = "\n".join(lines) + "\n"
    print(text)
    (HERE / "results" / "simulate_compile_options.md").write_text(text)


if __name__ == "__main__":
    main()
