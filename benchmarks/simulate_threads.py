"""`jthermo simulate`'s run program with JAX's CPU backend made as usual (an intra-op thread
pool of one thread per CPU) against `runtime.one_thread_backend()` (one thread).

Each row is a fresh process with no compilation cache: it builds the 16-zone printer, designs
lambda PI, then calls `closedloop.engine._quick_scenario_metrics()` (the run program with the
command's compile options) three times: the first call traces and compiles, the other two run.
CPU s are user + system of the whole process (all threads); modes interleaved.

    python benchmarks/simulate_threads.py [--repeats 3] [--out -]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

from common import finish, load

HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, sys, time
from jthermo import runtime
one = runtime.one_thread_backend() if sys.argv[1] == "one thread" else False
runtime.unroll_threefry()
import jax, equinox as eqx
jax.config.update("jax_enable_x64", True)
from jthermo import closedloop as cl
from jthermo.closedloop import engine
from jthermo.control.design import design
from jthermo.printer import make_printer
from jthermo.tune import printer_model
plant = make_printer(16, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
ctrl = design("pi_lambda", printer_model(plant))
args = ("tracking", plant, ctrl, 3600.0, jax.random.key(0), 256)
fn = engine._quick_scenario_metrics()
rows = []
for _ in range(3):
    w, c = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn(*args))
    rows.append((time.perf_counter() - w, time.process_time() - c))
print(json.dumps({"applied": one, "first_wall": rows[0][0], "first_cpu": rows[0][1],
                  "run_wall": min(r[0] for r in rows[1:]), "run_cpu": min(r[1] for r in rows[1:]),
                  "mse": float(out[0]["mse"]), "cost": float(out[0]["cost"])}))
"""

MODES = ("default", "one thread")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_threads.md"))
    args = ap.parse_args()
    load0 = load()
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env.update(JTHERMO_NO_CACHE="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    rows = []
    for _ in range(args.repeats):
        for mode in MODES:
            l0 = load()
            out = subprocess.run([sys.executable, "-c", CHILD, mode], env=env, check=True,
                                 capture_output=True, text=True).stdout
            rows.append({"mode": mode, "load": l0, **json.loads(out.strip().splitlines()[-1])})
            print(rows[-1], flush=True)
    lines = ["# `jthermo simulate`'s run program: CPU backend threads", "",
             (f"`python benchmarks/simulate_threads.py --repeats {args.repeats}`: N = 16, "
              "B = 256, T = 3600 s, a fresh process per row without compilation cache, modes "
              "interleaved; first call = trace + compile + run, run = the faster of two more "
              f"calls. {os.cpu_count()} CPUs shared with other jobs; 1-minute load before each "
              "row."), "",
             ("| backend | applied | first call wall s | first call CPU s | run wall s | "
              "run CPU s | mse | cost | load |"), "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['mode']} | {r['applied']} | {r['first_wall']:.2f} | "
                     f"{r['first_cpu']:.2f} | {r['run_wall']:.2f} | {r['run_cpu']:.2f} | "
                     f"{r['mse']!r} | {r['cost']!r} | {r['load']} |")
    lines += ["", "Medians:", ""]
    for mode in MODES:
        sel = [r for r in rows if r["mode"] == mode]

        def med(key, sel=sel):
            return statistics.median(r[key] for r in sel)

        lines.append(f"- {mode}: first call {med('first_wall'):.2f} s wall / "
                     f"{med('first_cpu'):.2f} CPU s, run {med('run_wall'):.2f} s wall / "
                     f"{med('run_cpu'):.2f} CPU s")
    finish(lines, load0, args.out)


if __name__ == "__main__":
    main()
