"""Compile options of the printer's scenario builder (`closedloop.scenarios._build_scenario`)
as tuning calls it: 4 zones, 16 rollouts, the training duration, the shared builder of the
three test kinds.

Each row is a fresh process with no compilation cache: lower, compile with the row's options,
then three calls. Reported: CPU s of the compile, seconds per call (the median of three), and
the largest difference of the built arrays from the default options' (the measurement noise
`v` is where rounding shows).

    python benchmarks/tuning_scenario_build.py

Not adopted: built with `runtime.one_shot()` at the top level, `tune --controller pi` took the
same CPU seconds cold (benchmarks/results/tuning_latency_ab_tune_pi_scenario_build.md).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from simulate_common import load

HERE = Path(__file__).resolve().parent
OPTIONS = {"default": {}, "runtime.one_shot()": "one_shot"}

CHILD = r"""
import json, sys, time
import jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from jthermo import closedloop as cl, runtime
from jthermo.closedloop import scenarios as S
from jthermo.printer import make_printer
from jthermo.tune import DURATION
opts = json.loads(sys.argv[1])
opts = runtime.one_shot() if opts == "one_shot" else opts
pr = make_printer(4, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
T = int(round(DURATION / pr.ts))
keys = jax.random.split(jax.random.key(0), 16)
flags = jnp.asarray(S.SHARED_KINDS["tracking"], pr.capacity.dtype)
args = ("shared", S.unlabelled(pr), None, T, keys, 0.05, float(S.STEP_C), True, flags)
c0 = time.process_time()
comp = S._build_scenario.lower(*args).compile(compiler_options=opts)
c1 = time.process_time()
calls = []
for _ in range(3):
    w = time.perf_counter()
    out = jax.block_until_ready(comp(*args))
    calls.append(time.perf_counter() - w)
np.savez(sys.argv[2], *[np.asarray(a) for a in jax.tree.leaves(out)])
print(json.dumps({"compile_cpu": c1 - c0, "call_s": sorted(calls)[1], "T": T}))
"""


def main() -> None:
    env = dict(os.environ, JTHERMO_NO_CACHE="1", OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    load0 = load()
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, opts) in enumerate(OPTIONS.items()):
            out = subprocess.run([sys.executable, "-c", CHILD, json.dumps(opts), f"{tmp}/{i}.npz"],
                                 env=env, check=True, capture_output=True, text=True).stdout
            rows[name] = json.loads(out.strip().splitlines()[-1])
            print(name, rows[name], flush=True)
        ref = np.load(f"{tmp}/0.npz")
        for i, name in enumerate(OPTIONS):
            now = np.load(f"{tmp}/{i}.npz")
            rows[name]["diff"] = max(float(np.max(np.abs(now[k] - ref[k]), initial=0.0))
                                     for k in ref.files)
    T = rows["default"]["T"]
    lines = [f"# Compile options of the scenario builder: 4 zones, 16 rollouts, {T} samples", "",
             ("`python benchmarks/tuning_scenario_build.py`: a fresh process per row, no "
              f"compilation cache. 1-minute load {load0} at the start, {load()} at the end (2 "
              "shared cores: CPU s are user + system of the process)."), "",
             "| XLA options | compile CPU s | s per call | largest difference from default |",
             "|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(f"| {name} | {r['compile_cpu']:.2f} | {r['call_s']:.4f} | {r['diff']:.3g} |")
    text = "\n".join(lines) + "\n"
    print(text)
    (HERE / "results" / "tuning_scenario_build.md").write_text(text)


if __name__ == "__main__":
    main()
