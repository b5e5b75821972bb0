"""Where the execution of `jthermo simulate`'s run program goes, kernel by kernel.

The program `closedloop.run` compiles for the printer (`engine._scenario_metrics_fn` with
`runtime.simulate_compile()` options, the command's one-thread backend and unrolled
Threefry) is compiled once, executed `--repeats` times (wall and CPU s of each; the minimum
is reported), then executed once more under `jax.profiler`: XLA's CPU thunks, summed by
name, split into the kernels run once per time step (inside the scan) and the others.

Runs against whatever `jthermo` is importable, so an A/B of two trees is two runs with
`PYTHONPATH` set to each (the `--label` names the row):

    python benchmarks/simulate_run_profile.py --label HEAD
    python benchmarks/simulate_run_profile.py --label O0 --option xla_backend_optimization_level=0 --append
    PYTHONPATH=/tmp/base python benchmarks/simulate_run_profile.py --label base --append

writes (or appends a section to) `benchmarks/results/simulate_run_profile.md`.
"""

from __future__ import annotations

import argparse
import collections
import glob
import os
import subprocess
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=256)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--kind", default="tracking")
    ap.add_argument("--controller", default="pi_lambda")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--label", default="this checkout")
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_run_profile.md"))
    ap.add_argument("--append", action="store_true", help="add a section to --out")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="an XLA compiler option over runtime.simulate_compile()'s (repeatable)")
    args = ap.parse_args()

    from jthermo import runtime

    runtime.unroll_threefry()
    import jax

    jax.config.update("jax_enable_x64", True)
    runtime.one_thread_backend()
    import equinox as eqx

    import jthermo
    from jthermo import closedloop as cl
    from jthermo.cli import control
    from jthermo.closedloop import engine
    from jthermo.control.design import design
    from jthermo.printer import make_printer

    plant = make_printer(args.zones, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
    ctrl = design(args.controller, control.stored_printer_model(plant))
    key = jax.random.key(0)
    call = (args.kind, plant, ctrl, args.duration, key, args.rollouts)
    options = dict(runtime.simulate_compile())
    options.update(kv.split("=", 1) for kv in args.option)
    fn = eqx.filter_jit(engine._scenario_metrics_fn, compiler_options=options)
    c0, t0 = time.process_time(), time.perf_counter()
    compiled = fn.lower(*call).compile()
    compile_wall, compile_cpu = time.perf_counter() - t0, time.process_time() - c0
    runs = []
    for _ in range(args.repeats):
        load = os.getloadavg()[0]
        c0, t0 = time.process_time(), time.perf_counter()
        out = jax.block_until_ready(compiled(*call))
        runs.append((time.perf_counter() - t0, time.process_time() - c0, load))
    metrics = {k: float(v) for k, v in out[0].items()}

    with tempfile.TemporaryDirectory(prefix="jthermo-prof-") as d:
        jax.profiler.start_trace(d)
        jax.block_until_ready(compiled(*call))
        jax.profiler.stop_trace()
        pd = jax.profiler.ProfileData.from_file(glob.glob(d + "/**/*.xplane.pb", recursive=True)[0])
        total, count = collections.Counter(), collections.Counter()
        for plane in pd.planes:
            for line in plane.lines:
                if not line.name.startswith("tf_XLAEigen"):
                    continue
                for ev in line.events:
                    if ev.name.startswith(("end:", "ThunkExecutor")):
                        continue
                    total[ev.name] += ev.duration_ns / 1e9
                    count[ev.name] += 1
    T = round(args.duration / plant.ts)
    per_step = {k for k in total if count[k] == T}
    src = Path(jthermo.__file__).resolve().parent.parent
    try:
        rev = subprocess.run(["git", "-C", str(src), "describe", "--always", "--dirty"],
                             capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        rev = "no git"
    w = sorted(runs)
    lines = [f"## {args.label} ({src}, {rev})", "", f"Compiler options {options}.", "",
             (f"{args.kind} / {args.controller}, N = {args.zones}, B = {args.rollouts}, "
              f"T = {T}: compile {compile_wall:.2f} s wall / {compile_cpu:.2f} CPU s; execution "
              f"over {args.repeats} runs: min {w[0][0]:.3f} s wall, min "
              f"{min(r[1] for r in runs):.3f} CPU s (all: "
              + ", ".join(f"{a:.2f}/{b:.2f}" for a, b, _ in runs)
              + f"; 1-minute load {min(r[2] for r in runs):.2f}-{max(r[2] for r in runs):.2f})."),
             "", (f"Profiled run: {len(per_step)} kernels per time step, "
                  f"{sum(total[k] for k in per_step):.3f} s in them; "
                  f"{sum(v for k, v in total.items() if k not in per_step):.3f} s in the "
                  f"{len(total) - len(per_step)} other kernels. mse {metrics['mse']!r}, "
                  f"settling_time_s {metrics['settling_time_s']!r}."), "",
             "| kernel | calls | s |", "|---|---|---|"]
    lines += [f"| {k} | {count[k]} | {v:.3f} |" for k, v in total.most_common(args.top)]
    text = "\n".join(lines) + "\n"
    out_path = Path(args.out)
    if args.append and out_path.exists():
        text = out_path.read_text() + "\n" + text
    else:
        text = ("# `jthermo simulate`'s run program, kernel by kernel\n\n"
                "`python benchmarks/simulate_run_profile.py` (see its docstring); wall "
                "seconds of the profiled kernels include the profiler's own overhead and the "
                "load of the shared 2-core machine.\n\n") + text
    out_path.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
