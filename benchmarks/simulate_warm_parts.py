"""The warm `jthermo simulate` run program in its parts: the exported program read
from disk, `jit(exported.call)` lowered (JAX initialises the CPU LAPACK kernels there, which
imports `scipy.linalg`: timed on its own), the executable loaded from the persistent
compilation cache, and executed.

Two child processes on a fresh cache (the first fills it, cold), the second measured (warm),
as the command runs (`runtime.enable_cache`, unrolled Threefry, one-thread backend):

    python benchmarks/simulate_warm_parts.py      # -> results/simulate_warm_parts.md
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

T_START = time.perf_counter()
HERE = Path(__file__).resolve().parent


def child(args) -> None:
    from jthermo import runtime, stored

    runtime.enable_cache()
    runtime.unroll_threefry()
    import jax

    jax.config.update("jax_enable_x64", True)
    runtime.one_thread_backend()
    from jthermo import closedloop as cl
    from jthermo.cli import control
    from jthermo.closedloop import engine
    from jthermo.control.design import design
    from jthermo.printer import make_printer

    rows, t = [], [time.perf_counter(), time.process_time()]

    def mark(stage):
        w, c = time.perf_counter(), time.process_time()
        rows.append((stage, w - t[0], c - t[1]))
        t[:] = [time.perf_counter(), time.process_time()]

    rows.append(("interpreter start to imports done", time.perf_counter() - T_START,
                 time.process_time()))
    plant = make_printer(args.zones, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
    ctrl = jax.block_until_ready(design("pi_lambda", control.stored_printer_model(plant)))
    mark("printer, design model, pi_lambda")
    fn_args = ("tracking", plant, ctrl, args.duration, jax.random.key(0), args.rollouts)
    exp, arrays = stored._exported_program(engine._scenario_metrics_fn, fn_args)
    mark("exported program read")
    had_scipy = "scipy.linalg" in sys.modules
    if not had_scipy:
        import scipy.linalg  # noqa: F401  (what the lowering's LAPACK initialisation imports)
    mark("import scipy.linalg (LAPACK initialisation)" + (" (already loaded)" if had_scipy else ""))
    lowered = stored._caller(exp, runtime.simulate_compile()).lower(*arrays)
    mark("lower jit(exported.call)")
    compiled = lowered.compile()
    mark("executable from the persistent cache")
    out = jax.block_until_ready(compiled(*arrays))
    mark("execute")
    print(json.dumps({"rows": rows, "mse": float(out[0]["mse"]),
                      "load": os.getloadavg()[0]}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=256)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_warm_parts.md"))
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args)
    with tempfile.TemporaryDirectory(prefix="jthermo-warm-") as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
        env.pop("JTHERMO_NO_CACHE", None)
        env["JTHERMO_CACHE_DIR"] = tmp
        cmd = [sys.executable, __file__, "--child", "--zones", str(args.zones), "--rollouts",
               str(args.rollouts), "--duration", str(args.duration)]
        subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)   # cold
        load0 = os.getloadavg()[0]
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
    rep = json.loads(r.stdout.strip().splitlines()[-1])
    lines = [f"# Warm `jthermo simulate` run program in parts: N = {args.zones}, "
             f"B = {args.rollouts}, T = {args.duration:g} s", "",
             ("`python benchmarks/simulate_warm_parts.py`: a second process on the cache a "
              f"first one filled; 1-minute load {load0:.2f} before it, {rep['load']:.2f} after "
              f"(2 shared cores). mse {rep['mse']!r}."), "",
             "| part | wall s | CPU s |", "|---|---|---|"]
    lines += [f"| {s} | {w:.2f} | {c:.2f} |" for s, w, c in rep["rows"]]
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
