"""Compile time of a program run once (`runtime.ONE_SHOT`): the printer's design model.

Each row is a fresh process with no compilation cache: it builds the N-zone virtual printer and
compiles and runs `tune.printer_model` (the Jacobians of the one-sample map) as one program,
with XLA's default options, with LLVM at -O0 alone (`runtime.ONE_SHOT` until 2026-11-25) and with
`runtime.ONE_SHOT` (-O0 and XLA's older CPU fusion emitters). Reported: wall and CPU seconds
(user + system of the process, import excluded), and the largest difference of the model's A
matrix from the default's (what the controller design downstream sees).

    python benchmarks/one_shot_compile.py [--zones 16] [--repeats 3]
    python benchmarks/one_shot_compile.py --zones 4     # tune's printer
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent

CHILD = r"""
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import equinox as eqx, numpy as np
from jthermo import closedloop as cl, runtime, tune
from jthermo.printer import make_printer
p = make_printer(int(sys.argv[1]), cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
opts = {"default": {}, "O0": {"xla_backend_optimization_level": 0},
        "one_shot": runtime.ONE_SHOT}[sys.argv[2]]
t, w = time.process_time(), time.perf_counter()
m = eqx.filter_jit(tune.printer_model, compiler_options=opts)(p)
A = np.asarray(jax.block_until_ready(m.A))
out = {"wall": time.perf_counter() - w, "cpu": time.process_time() - t}
np.save(sys.argv[3], A)
print(json.dumps(out))
"""


def _run(zones: int, mode: str, npy: str) -> dict:
    env = dict(os.environ, JTHERMO_NO_CACHE="1", OPENBLAS_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD, str(zones), mode, npy], env=env,
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    import numpy as np

    sys.path.insert(0, str(HERE.parent))
    from jthermo import runtime

    ap = argparse.ArgumentParser()
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=None, help="default benchmarks/results/one_shot_compile.md")
    args = ap.parse_args()
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        load0 = os.getloadavg()[0]
        for mode in ("default", "O0", "one_shot"):
            runs = [_run(args.zones, mode, f"{tmp}/{mode}.npy") for _ in range(args.repeats)]
            rows[mode] = {k: float(np.median([r[k] for r in runs])) for k in ("wall", "cpu")}
            rows[mode]["diff"] = float(np.max(np.abs(np.load(f"{tmp}/default.npy")
                                                     - np.load(f"{tmp}/{mode}.npy"))))
    load = os.getloadavg()[0]
    lines = ["# Compile options of a program run once: the printer's design model", "",
             f"`python benchmarks/one_shot_compile.py --zones {args.zones} --repeats {args.repeats}`: "
             "a fresh process, no compilation cache, median of the repeats; seconds exclude the "
             f"imports. 1-minute load {load0:.2f} at the start, {load:.2f} at the end (2 shared "
             "cores: wall s follow the load, CPU s less so).", "",
             "| XLA options | wall s | CPU s | largest difference of A from default |",
             "|---|---|---|---|"]
    names = {"default": "default", "O0": "LLVM -O0 (ONE_SHOT before)",
             "one_shot": f"runtime.ONE_SHOT = {runtime.ONE_SHOT}"}
    for mode, r in rows.items():
        lines.append(f"| {names[mode]} | {r['wall']:.2f} | {r['cpu']:.2f} | {r['diff']:.3g} |")
    out = args.out or str(HERE / "results" / "one_shot_compile.md")
    Path(out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
