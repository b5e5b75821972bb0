"""Compile and run seconds of `jthermo tune`'s evaluation program (`tune.terms._group_terms_fn`:
cost and mse of one controller on a grouped batch) for every controller structure of the
default report (the start designs of pi and lqg and the classical designs), under XLA option
sets, each in a fresh process with no compilation cache, and the largest difference of its
figures from the first option set's.

The batch is the default report's held-out chunk (`tune_report` at the CLI's defaults: 4 zones,
16 rollouts, 600 s, 3 plants x 3 scenarios = 9 items), built as `tune_report` builds it.

    python benchmarks/tune_program_options.py \
        --options quick='{"xla_cpu_use_fusion_emitters": false}' \
        --options o1='{"xla_cpu_use_fusion_emitters": false, "xla_backend_optimization_level": 1}'
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

from common import cpu_seconds  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"



def child(options: dict, out: str, repeats: int) -> int:
    import equinox as eqx
    import jax
    import numpy as np
    from jax import monitoring

    from jthermo import runtime
    from jthermo.control.design import design
    from jthermo.tune import report, terms, training

    runtime.disable_cache("benchmark: every compile paid")
    runtime.unroll_threefry()           # as the `jthermo` command does at start-up
    events: list[float] = []
    monitoring.register_event_duration_secs_listener(
        lambda ev, dur, **_: events.append(dur) if "backend_compile" in ev else None)
    pl = report._plant_from("printer", zones=4, powder="PA12", plant_seed=0)
    ens = training.plant_ensemble(pl, 2, seed=0)
    model = report._printer_model(pl)
    plants = {"plant": pl,
              "changed": report._plant_from("printer", zones=4, powder="PA11", plant_seed=0)}
    plants.update(report._gain_plants(pl, 0.2))
    _, batches = report.held_out_study(plants, (training.HELD_OUT,), rollouts=16,
                                       duration=600.0, chunk=len(ens) * 3)
    ctrls = {"lqg": report.rescaled_start(design("lqg", model)), **report.classical_designs(model)}
    seen, todo = [], {}
    for name, c in ctrls.items():
        s = jax.tree_util.tree_structure(c)
        if s not in seen:
            seen.append(s)
            todo[name] = c
    fn = eqx.filter_jit(terms._group_terms_fn, compiler_options=runtime.accepted(options) or None)
    rows, values = {}, {}
    for name, c in todo.items():
        n0, t0, c0 = len(events), time.perf_counter(), cpu_seconds()
        v = np.asarray(fn(c, batches[0], None))
        first, first_cpu = time.perf_counter() - t0, cpu_seconds() - c0
        runs = []
        for _ in range(repeats):
            t1 = time.perf_counter()
            v = np.asarray(fn(c, batches[0], None))
            runs.append(time.perf_counter() - t1)
        rows[name] = {"first": first, "first_cpu": first_cpu,
                      "backend": sum(events[n0:]), "run": min(runs), "runs": runs}
        values[name] = v.tolist()
    Path(out).write_text(json.dumps({"rows": rows, "values": values}))
    return 0


def child_step(options: dict, out: str, controller: str) -> int:
    """Adam's training step of `jthermo tune --controller C` (CLI defaults) under `options`:
    seconds to the first iterate (trace + compile + two steps), then per step."""
    import jax
    import numpy as np

    from jthermo import runtime
    from jthermo.cli import control as cc
    from jthermo.control.design import design
    from jthermo.tune import optimiser, report, training

    runtime.disable_cache("benchmark: every compile paid")
    runtime.unroll_threefry()           # as the `jthermo` command does at start-up
    fam = {"pi": "pi_lambda"}.get(controller, controller)
    pl = report._plant_from("printer", zones=4, powder="PA12", plant_seed=0)
    ens = training.plant_ensemble(pl, 2, seed=0)
    model = report._printer_model(pl)
    start = report.rescaled_start(design(fam, model))
    refs = [design(f, model) for f in ("pi_lambda",) if f != fam]
    train, _ = report._training_sets(ens, 16, 600.0, 0)
    optimiser.STEP_COMPILE = options
    marks: list[tuple[float, float]] = []
    inner = training.minimise

    def timed_minimise(*a, **k):
        marks.append((time.perf_counter(), time.process_time()))
        return inner(*a, **k)

    training.minimise = timed_minimise
    res = training.tune(start, pl, plants=ens, scenarios=train, references=refs,
                        steps=cc.SHORT_STEPS[fam], lr=cc.SHORT_LR.get(fam, 0.05), guard=False,
                        train_dtype=cc.TRAIN_DTYPE.get(fam),
                        progress=lambda i, c: marks.append((time.perf_counter(),
                                                            time.process_time())))
    (w0, c0), (w1, c1), (wn, cn) = marks[0], marks[1], marks[-1]
    k = len(marks) - 2
    leaves = [np.asarray(x).tolist() for x in jax.tree_util.tree_leaves(res.controller)]
    Path(out).write_text(json.dumps({"first_wall": w1 - w0, "first_cpu": c1 - c0,
                                     "step_wall": (wn - w1) / k, "step_cpu": (cn - c1) / k,
                                     "history": [float(h) for h in res.history],
                                     "leaves": leaves}))
    return 0


def child_scenario(options: dict, out: str) -> int:
    """The scenario builder (`closedloop.scenarios._build_scenario`) under `options`, on the
    default report's workload: the training and validation sets (3 plants x 3 kinds each) and
    the held-out study (4 plants x 3 kinds), 16 rollouts x 600 s."""
    import equinox as eqx
    import jax
    import numpy as np

    from jthermo import runtime
    from jthermo.closedloop import scenarios
    from jthermo.tune import report, training

    runtime.disable_cache("benchmark: every compile paid")
    runtime.unroll_threefry()           # as the `jthermo` command does at start-up
    scenarios._build_scenario = eqx.filter_jit(scenarios._build_scenario.__wrapped__,  # noqa
                                               compiler_options=runtime.accepted(options) or None)
    pl = report._plant_from("printer", zones=4, powder="PA12", plant_seed=0)
    ens = training.plant_ensemble(pl, 2, seed=0)
    plants = {"plant": pl,
              "changed": report._plant_from("printer", zones=4, powder="PA11", plant_seed=0)}
    plants.update(report._gain_plants(pl, 0.2))
    w0, c0 = time.perf_counter(), time.process_time()
    first = training.make_batches(ens[:1], ("tracking",), rollouts=16, duration=600.0, seed=0)
    jax.block_until_ready(first[0][0][2].r)
    w1, c1 = time.perf_counter(), time.process_time()
    train, val = report._training_sets(ens, 16, 600.0, 0)
    _, study = report.held_out_study(plants, (training.HELD_OUT,), rollouts=16, duration=600.0,
                                     chunk=9)
    leaves = jax.tree_util.tree_leaves((train, val, study))
    jax.block_until_ready(leaves)
    w2, c2 = time.perf_counter(), time.process_time()
    flat = [np.asarray(x, np.float64).ravel() for x in leaves
            if eqx.is_array(x) and not jax.dtypes.issubdtype(x.dtype, jax.dtypes.extended)]
    Path(out).write_text(json.dumps({"first_wall": w1 - w0, "first_cpu": c1 - c0,
                                     "rest_wall": w2 - w1, "rest_cpu": c2 - c1,
                                     "values": np.concatenate(flat).tolist()}))
    return 0


def scenario_table(args, sets, res, base) -> int:
    import numpy as np

    lines = ["# The scenario builder of `jthermo tune` under XLA options", "",
             "`python benchmarks/tune_program_options.py --program scenario " + " ".join(
                 f"--options {lab}='{o}'" for lab, o in sets)
             + "`: one fresh process per option set, no compilation cache. first = the first "
             "scenario (trace + compile + run), rest = the default report's 30 other "
             "scenario batches (training, validation, held-out; 16 rollouts x 600 s); "
             f"largest difference of every scenario array from `{base}`'s.", "",
             "| options | process wall s, CPU s, load | first wall s | first CPU s | rest wall s "
             "| rest CPU s | max abs diff | max rel diff |", "|---|---|---|---|---|---|---|---|"]
    for label, r in res.items():
        a, b = np.asarray(r["values"]), np.asarray(res[base]["values"])
        d = np.abs(a - b)
        lines.append(f"| `{label}` {r['options']} | {r['wall']:.1f}, {r['cpu']:.1f}, "
                     f"{r['load']:.2f} | {r['first_wall']:.2f} | {r['first_cpu']:.2f} | "
                     f"{r['rest_wall']:.2f} | {r['rest_cpu']:.2f} | {float(np.max(d)):.3g} | "
                     f"{float(np.max(d / np.maximum(np.abs(b), 1e-300))):.3g} |")
    path = RESULTS / "tune_program_options_scenario.md"
    path.write_text("\n".join(lines) + "\n")
    print(path.read_text())
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--options", action="append", default=[], metavar="LABEL=JSON")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--program", choices=("terms", "step", "scenario"), default="terms",
                    help="the evaluation program per structure, or Adam's training step")
    ap.add_argument("--controller", default="lqg", help="with --program step: pi or lqg")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child is not None and args.program == "scenario":
        return child_scenario(json.loads(args.child), args.out)
    if args.child is not None and args.program == "step":
        return child_step(json.loads(args.child), args.out, args.controller)
    if args.child is not None:
        return child(json.loads(args.child), args.out, args.repeats)
    sets = [tuple(o.split("=", 1)) for o in args.options] or [
        ("quick", '{"xla_cpu_use_fusion_emitters": false}')]
    res = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, opts in sets:
            out = os.path.join(tmp, f"{label}.json")
            load = os.getloadavg()[0]
            t0 = time.perf_counter()
            p = subprocess.Popen([sys.executable, __file__, "--child", opts, "--out", out,
                                  "--repeats", str(args.repeats), "--program", args.program,
                                  "--controller", args.controller], cwd=ROOT)
            _, status, ru = os.wait4(p.pid, 0)
            if os.waitstatus_to_exitcode(status):
                raise SystemExit(f"child {label} failed")
            res[label] = {**json.loads(Path(out).read_text()), "load": load,
                          "wall": time.perf_counter() - t0, "cpu": ru.ru_utime + ru.ru_stime,
                          "options": opts}
    import numpy as np

    base = sets[0][0]
    if args.program == "step":
        return step_table(args, sets, res, base)
    if args.program == "scenario":
        return scenario_table(args, sets, res, base)
    lines = ["# `tune.terms._group_terms_fn` per controller structure under XLA options", "",
             "`python benchmarks/tune_program_options.py " + " ".join(
                 f"--options {lab}='{o}'" for lab, o in sets) + "`: one fresh process per "
             "option set, no compilation cache; batch: the default report's held-out chunk (9 "
             "items x 16 rollouts x 600 s). first = trace + compile + first run (wall s, CPU "
             "s), backend = XLA compile s, run = the fastest of the next runs (wall s); "
             f"max |diff| against `{base}`'s figures (cost, mse per item).", ""]
    lines += ["| options | process wall s, CPU s, load | structure | first wall s | first CPU s "
              "| backend s | run s | max abs diff | max rel diff |",
              "|---|---|---|---|---|---|---|---|---|"]
    for label, r in res.items():
        head = f"`{label}` {r['options']} | {r['wall']:.1f}, {r['cpu']:.1f}, {r['load']:.2f}"
        for i, (name, row) in enumerate(r["rows"].items()):
            a, b = np.asarray(r["values"][name]), np.asarray(res[base]["values"][name])
            d = float(np.max(np.abs(a - b)))
            rel = float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))
            lines.append(f"| {head if i == 0 else ' | '} | {name} | "
                         f"{row['first']:.2f} | {row['first_cpu']:.2f} | {row['backend']:.2f} | "
                         f"{row['run']:.3f} | {d:.3g} | {rel:.3g} |")
        tot = {k: sum(row[k] for row in r["rows"].values()) for k in ("first", "first_cpu",
                                                                     "backend", "run")}
        lines.append(f"| | | all | {tot['first']:.2f} | {tot['first_cpu']:.2f} | "
                     f"{tot['backend']:.2f} | {tot['run']:.3f} | | |")
    path = RESULTS / "tune_program_options.md"
    path.write_text("\n".join(lines) + "\n")
    print(path.read_text())
    return 0


def step_table(args, sets, res, base) -> int:
    import numpy as np

    lines = [f"# Adam's training step of `jthermo tune --controller {args.controller}` under XLA "
             "options", "",
             f"`python benchmarks/tune_program_options.py --program step --controller "
             f"{args.controller} " + " ".join(f"--options {lab}='{o}'" for lab, o in sets)
             + "`: one fresh process per option set, no compilation cache; `tune` at the CLI's "
             "defaults without the guard. first = from `minimise`'s call to its first iterate "
             "(trace + compile + two steps), step = per further step (wall s, process CPU s); "
             f"largest relative difference of the training history and of the tuned "
             f"controller's leaves from `{base}`'s.", "",
             "| options | process wall s, CPU s, load | first wall s | first CPU s | step wall s "
             "| step CPU s | history rel diff | leaves rel diff |",
             "|---|---|---|---|---|---|---|---|"]
    rel = lambda a, b: float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-300)))
    for label, r in res.items():
        b = res[base]
        h = rel(np.asarray(r["history"]), np.asarray(b["history"]))
        lv = max(rel(np.asarray(x), np.asarray(y)) for x, y in zip(r["leaves"], b["leaves"]))
        lines.append(f"| `{label}` {r['options']} | {r['wall']:.1f}, {r['cpu']:.1f}, "
                     f"{r['load']:.2f} | {r['first_wall']:.2f} | {r['first_cpu']:.2f} | "
                     f"{r['step_wall']:.3f} | {r['step_cpu']:.3f} | {h:.3g} | {lv:.3g} |")
    path = RESULTS / f"tune_program_options_step_{args.controller}.md"
    path.write_text("\n".join(lines) + "\n")
    print(path.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
