"""Where `jthermo simulate` spends its time: the command's stages timed one by
one in this process, each with its wall and CPU seconds and the JAX compile events it caused.

Stages, as `jthermo.cli.control.cmd_simulate` runs them: import, `make_printer`, the design
model (`tune.printer_model`), the controller design, then `closedloop.run`'s program: the
scenarios drawn and the figures accumulated inside the scan, no `(B, T, n)` array returned.
With `--dense` the earlier path follows for comparison: `make_scenario`, stored trajectories,
then `metrics` and `cost`. Each runs twice (the second call is the warm one in a process).
Compile events come from `jax.monitoring` (trace, lowering,
backend compile: count and seconds); a warm persistent cache still traces and lowers.

    python benchmarks/simulate_profile.py                 # N = 16, B = 256, T = 3600
    python benchmarks/simulate_profile.py --rollouts 32 --duration 600 --out -   # quick look

Run it twice with the same `JTHERMO_CACHE_DIR` for the warm-cache profile. `--imports` times
the imports alone instead (a fresh interpreter per import, median of 5: `import jthermo` is
lazy; the simulate command's stack is JAX, equinox, closedloop, design and tune). CPU seconds (user +
system of this process, all threads) are less sensitive than wall seconds to other jobs on a
shared machine; the load average is recorded at the start and the end.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time
from pathlib import Path

from common import load  # noqa: E402

T_START = time.perf_counter()
CPU_START = time.process_time()

HERE = Path(__file__).resolve().parent
EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "compile"}
_seen: collections.Counter = collections.Counter()
_secs: collections.Counter = collections.Counter()


def _on_span(event: str, start: float, end: float, **_) -> None:
    if event in EVENTS:
        _seen[EVENTS[event]] += 1
        _secs[EVENTS[event]] += end - start


def _cache_entries() -> int:
    """Entries in the persistent compilation cache (`JTHERMO_CACHE_DIR` or the default)."""
    from jthermo import runtime

    d = runtime.default_cache_dir()
    return sum(1 for p in d.iterdir() if p.name.endswith("-cache")) if d.is_dir() else 0



def stage(rows: list, name: str, fn):
    """Run `fn()`, block on its result, append a row; return the result."""
    import jax

    seen, secs = _seen.copy(), _secs.copy()
    t0, c0 = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn())
    rows.append({"stage": name, "wall_s": time.perf_counter() - t0,
                 "cpu_s": time.process_time() - c0,
                 **{k: _seen[k] - seen[k] for k in EVENTS.values()},
                 "compile_events_s": sum(_secs.values()) - sum(secs.values())})
    print(rows[-1], flush=True)
    return out


def hlo_ops(fn, *args, top: int = 12) -> list[str]:
    """Markdown rows: the most frequent HLO opcodes of the optimised program of `fn(*args)`
    (an `eqx.filter_jit` function), with the fused computations counted inside."""
    import re

    text = fn.lower(*args).compile().compiled.as_text()   # equinox wraps jax's Compiled
    ops = collections.Counter(re.findall(r"^\s*(?:ROOT )?%?[\w.-]+ = .*? ([a-z][a-z0-9-]*)\(",
                                         text, re.MULTILINE))
    rows = [f"| {op} | {n} |" for op, n in ops.most_common(top)]
    return [(f"HLO of the run program after XLA's optimisation: {sum(ops.values())} "
             f"instructions, {ops['fusion']} fusions, {ops['while']} while loops."), "",
            "| opcode | count |",
            "|---|---|", *rows]


IMPORTS = {"jthermo": "import jthermo", "jthermo.cli (the command's parser)": "import jthermo.cli",
           "jax": "import jax",
           "simulate's stack (closedloop, control.design, tune)":
               "import jthermo.closedloop, jthermo.control.design, jthermo.tune"}


def imports(out: str) -> None:
    """Median wall and CPU seconds of each import in `IMPORTS`, a fresh interpreter each."""
    import statistics
    import subprocess

    probe = ("import time; w, c = time.perf_counter(), time.process_time(); {stmt}; "
             "print(time.perf_counter() - w, time.process_time() - c)")
    load0 = load()
    lines = ["# Import times", "",
             (f"`python benchmarks/simulate_profile.py --imports`: a fresh interpreter per import, "
              f"median of 5; 1-minute load {load0} at the start, {{load1}} at the end (2 shared "
              "cores)."), "", "| import | wall s | CPU s | heavy modules loaded |", "|---|---|---|---|"]
    heavy = ("matplotlib", "pandas", "optimistix", "optax", "scipy")
    for name, stmt in IMPORTS.items():
        runs = [subprocess.run([sys.executable, "-c", probe.format(stmt=stmt)], check=True,
                               capture_output=True, text=True).stdout.split() for _ in range(5)]
        check = f"import sys; {stmt}; print(' '.join(m for m in {heavy!r} if m in sys.modules))"
        mods = subprocess.run([sys.executable, "-c", check], check=True, capture_output=True,
                              text=True).stdout.strip()
        lines.append(f"| `{stmt}` ({name}) | {statistics.median(float(r[0]) for r in runs):.3f} | "
                     f"{statistics.median(float(r[1]) for r in runs):.3f} | {mods or 'none'} |")
        print(lines[-1], flush=True)
    text = "\n".join(lines).replace("{load1}", load()) + "\n"
    print(text)
    if out != "-":
        Path(out).write_text(text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=256)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--dense", action=argparse.BooleanOptionalAction, default=True,
                    help="also time the dense metrics path")
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_profile.md"),
                    help="Markdown file to write ('-': print only)")
    ap.add_argument("--imports", action="store_true", help="time the imports only")
    ap.add_argument("--hlo", action="store_true",
                    help="add the HLO opcode counts of the run program")
    args = ap.parse_args()
    if args.imports:
        imports(args.out if args.out != str(HERE / "results" / "simulate_profile.md")
                else str(HERE / "results" / "import_times.md"))
        return
    load0 = load()
    n_cache0 = _cache_entries()
    rows: list = []
    t0, c0 = time.perf_counter(), time.process_time()
    from jthermo import runtime

    runtime.enable_cache()
    runtime.unroll_threefry()   # as the command does
    import jax

    jax.config.update("jax_enable_x64", True)
    jax.monitoring.register_event_time_span_listener(_on_span)
    import equinox as eqx

    from jthermo import closedloop as cl
    from jthermo.closedloop import engine
    from jthermo.control.design import design
    from jthermo.printer import make_printer
    from jthermo.tune import printer_model

    rows.append({"stage": "import (python start to jthermo.closedloop, tune, design loaded)",
                 "wall_s": time.perf_counter() - T_START, "cpu_s": time.process_time() - CPU_START,
                 "trace": 0, "lower": 0, "compile": 0, "compile_events_s": 0.0})
    print(rows[-1], flush=True)
    del t0, c0
    plant = stage(rows, "make_printer", lambda: make_printer(
        args.zones, cl.REALISTIC_EFFECTS, powder="PA12", seed=0))
    model = stage(rows, "design model (tune.printer_model, one jit as in the CLI)",
                  lambda: eqx.filter_jit(printer_model)(plant))
    ctrl = stage(rows, "design pi_lambda", lambda: design("pi_lambda", model))
    key = jax.random.key(0)
    lean = None
    for rep in ("first", "second"):
        lean = stage(rows, f"scenarios + lean metrics, one program as in `run` ({rep} call)",
                     lambda: engine.scenario_metrics("tracking", plant, ctrl, args.duration,
                                                      key, args.rollouts))
    noise = eqx.filter_jit(lambda k: jax.vmap(lambda kk: plant.sample_noise(
        kk, round(args.duration / plant.ts), 0.05))(jax.random.split(k, args.rollouts)))
    for rep in ("first", "second"):
        stage(rows, f"measurement noise alone (sample_noise of every rollout, {rep} call)",
              lambda: noise(key))
    if args.dense:
        sc = stage(rows, "make_scenario (dense path)", lambda: cl.make_scenario(
            "tracking", plant, args.duration, key, n_rollouts=args.rollouts))
        dense = eqx.filter_jit(lambda p, c, s: engine.rollouts_and_cost(p, c, s))
        for rep in ("first", "second"):
            traj, J = stage(rows, f"dense trajectories + cost ({rep} call)",
                            lambda: dense(plant, ctrl, sc))
            m = stage(rows, f"dense metrics ({rep} call)", lambda t=traj: cl.metrics(t, sc))
        del traj
        worst = max(abs(float(lean[0][k]) - m[k]) for k in m)
        print("max |lean - dense| over the metrics:", worst, " cost:", abs(float(lean[0]["cost"]) - float(J)))
    rows.append({"stage": "total (this process)", "wall_s": time.perf_counter() - T_START,
                 "cpu_s": time.process_time() - CPU_START, **{k: _seen[k] for k in EVENTS.values()},
                 "compile_events_s": sum(_secs.values())})
    load1 = load()
    lines = [(f"# `jthermo simulate` profile: N = {args.zones}, B = {args.rollouts}, "
              f"T = {args.duration:g} s"), "",
             (f"`python benchmarks/simulate_profile.py --zones {args.zones} --rollouts "
              f"{args.rollouts} --duration {args.duration:g}"
              f"{'' if args.dense else ' --no-dense'}{' --hlo' if args.hlo else ''}`, "
              "compilation cache entries "
              f"{n_cache0} at the start, {_cache_entries()} at the end; "
              f"1-minute load {load0} at the start, {load1} at the end (2 shared cores: wall "
              "seconds scale with the load, CPU seconds less so)."), "",
             "| stage | wall s | CPU s | traces | lowerings | backend compiles | compile-event s |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['stage']} | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | {r['trace']} | "
                     f"{r['lower']} | {r['compile']} | {r['compile_events_s']:.2f} |")
    if args.hlo:
        lines += ["", *hlo_ops(engine.scenario_metrics, "tracking", plant, ctrl, args.duration,
                               key, args.rollouts)]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out != "-":
        Path(args.out).write_text(text.replace(os.path.expanduser("~"), "~"))


if __name__ == "__main__":
    sys.exit(main())
