"""Cold cost of `jthermo demo`'s scenario stage: the held-out evaluation of every classical
design (`tune.evaluate`) and the three runs behind its figures, compiled as before (the
rollouts and their cost jitted with XLA's default options, the metrics in their own program,
`make_scenario` and `closedloop.simulate` eager) against now (`closedloop.compiled_make_scenario`, (`evaluate`'s one program per
controller structure and kind with `runtime.simulate_compile()` options, `make_scenario` as one
program with `runtime.one_shot()` options, the figures' runs through `demo._quick_simulate`).

Each mode runs in a fresh process with an empty compilation cache, the modes interleaved;
wall and CPU s (user + sys) per part, and the figures (cost and mse per scenario) of both:

    python benchmarks/evaluate_compile.py                # writes benchmarks/results/evaluate_compile.md
    python benchmarks/evaluate_compile.py --repeats 1 --out -
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from common import cold_child

ROOT = Path(__file__).resolve().parent.parent


def child(mode: str) -> dict:
    import equinox as eqx
    import jax
    import numpy as np

    from jthermo import closedloop as cl
    from jthermo import demo, runtime
    from jthermo.control.design import FAMILIES, design
    from jthermo.errors import JThermoError
    from jthermo.printer import make_printer
    from jthermo.tune import HELD_OUT, SCENARIOS, evaluate, printer_model

    jax.config.update("jax_enable_x64", True)
    runtime.enable_cache()
    runtime.unroll_threefry()
    plant = make_printer(4, cl.REALISTIC_EFFECTS, seed=0)
    base = printer_model(plant)
    ctrls = {}
    for fam in FAMILIES:
        try:
            ctrls[fam] = design(fam, base)
        except JThermoError:
            pass

    @eqx.filter_jit
    def before_cost(plant, controller, scenarios, weights):
        traj = cl.rollouts(plant, controller, scenarios)
        return traj, cl.cost(traj, scenarios, weights)

    def before(ctrl):
        out = {}
        for k in SCENARIOS:
            sc = cl.make_scenario(k, plant, 600.0, jax.random.key(HELD_OUT), n_rollouts=4)
            traj, J = before_cost(plant, ctrl, sc, None)
            out[k] = {"cost": float(J), **cl.metrics(traj, sc)}
        return out

    rows, figures = [], {}
    w0, c0 = time.perf_counter(), time.process_time()
    for name, ctrl in ctrls.items():
        if mode == "before":
            sc = before(ctrl)
        else:
            sc = evaluate(ctrl, plant, SCENARIOS, (HELD_OUT,), rollouts=4, duration=600.0)["scenarios"]
        figures[name] = {k: [v["cost"], v["mse"]] for k, v in sc.items()}
    rows.append(["held-out evaluation of %d designs" % len(ctrls), time.perf_counter() - w0,
                 time.process_time() - c0])
    w0, c0 = time.perf_counter(), time.process_time()
    sim = cl.simulate if mode == "before" else demo._quick_simulate()
    last = {}
    for k in SCENARIOS:
        build = cl.make_scenario if mode == "before" else cl.compiled_make_scenario()
        sc = build(k, plant, 600.0, jax.random.key(HELD_OUT))
        tr = sim(plant, ctrls["pi_lambda"], sc)
        last[k] = float(np.asarray(tr.y)[-1].mean())
    rows.append(["three figure runs", time.perf_counter() - w0, time.process_time() - c0])
    return {"rows": rows, "figures": figures, "last": last}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/evaluate_compile.md"))
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(args.child)))
        return
    runs = []
    for _ in range(args.repeats):
        for mode in ("before", "now"):
            runs.append((mode, *cold_child(__file__, mode)))
    by = {m: [r for mm, _, r in runs if mm == m][0] for m in ("before", "now")}
    worst = max(abs(a - b) / max(abs(a), 1e-300)
                for name, kinds in by["before"]["figures"].items()
                for k, pair in kinds.items() for a, b in zip(pair, by["now"]["figures"][name][k]))
    lines = ["# Cold cost of `jthermo demo`'s scenario stage: evaluation programs", "",
             f"`python benchmarks/evaluate_compile.py --repeats {args.repeats}`: N = 4, 600 s, 4 rollouts, "
             "each mode in a fresh process with an empty compilation cache, modes interleaved; "
             "2 shared CPUs, 1-minute load before each process. See the script's docstring for "
             "the two modes.", "",
             "| mode | part | wall s | CPU s | load |", "|---|---|---|---|---|"]
    for mode, load, r in runs:
        for part, w, c in r["rows"]:
            lines.append(f"| {mode} | {part} | {w:.2f} | {c:.2f} | {load} |")
    lines += ["", f"Largest relative difference of a cost or mse between the modes: {worst:.2e}; "
              f"last mean reading of the figure runs: before {by['before']['last']}, "
              f"now {by['now']['last']}."]
    text = "\n".join(lines) + "\n"
    if args.out == "-":
        print(text)
    else:
        Path(args.out).write_text(text)
        print(text)


if __name__ == "__main__":
    main()
