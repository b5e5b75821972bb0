"""`jthermo simulate`, `jthermo generate` and `jthermo tune`: the virtual printer in closed and
open loop, and gradient tuning of a controller family (the printer's design model that
`simulate` designs on: `printer_model`)."""

from __future__ import annotations

import argparse
import inspect
import time
from typing import Any

from ..errors import ConfigError
from ..families import SCENARIO_KINDS
from .common import (
    MAX_ROLLOUTS,
    MAX_ZONES,
    add_common,
    distinct_outputs,
    duration,
    info,
    input_file,
    output_path,
    plot_dir,
    positive_int,
    progress_bar,
    require,
    seed,
    summary_line,
    write_report,
)
from .printer_model import PREPARE_SKIP, prepare_in_background, stored_printer_model

#: `jthermo tune`'s default Adam iterations on the virtual printer for the families where
#: fewer were measured as good: with 150 the validation guard (Ms <= 2) chose iteration 60
#: for pi and 30 for lqg; with 60, pi returns the same controller (measured by
#: `python benchmarks/tuning_optimisers.py`); lqg at
#: 30 steps of learning rate 0.1 (`SHORT_LR`) does as well below lambda PI as at 60 steps of
#: 0.05 or at 150 (measured by `python benchmarks/tuning_rollouts.py`); pi at 40 steps of 0.075
#: falls short
SHORT_STEPS = {"pi_lambda": 60, "lqg": 30}
#: ... and their Adam learning rate where it is not `tune_report`'s 0.05
SHORT_LR = {"lqg": 0.1}
#: families whose training rollouts on the virtual printer run in float32 (`tune_report(
#: train_dtype=...)`; the guard and every held-out figure stay float64): pi does as well below
#: lambda PI as in float64, for less CPU per Adam step; lqg loses points and stays float64
#: (measured by `python benchmarks/tuning_rollouts.py`)
TRAIN_DTYPE = {"pi_lambda": "float32"}
#: ... every other family, and any family on a fitted plant (`tune_own_plant`): pi_ff and
#: lqg_ff lose 7 and 11 points against the best classical design at 60
DEFAULT_STEPS = 150
#: the virtual printer `simulate` and `tune` use when no --zones / --powder is given
PRINTER_ZONES, PRINTER_POWDER = 4, "PA12"
#: from this many zones on (the smallest bed the printer study measures), the families of
#: `MANY_ZONES_STEPS` take that many Adam iterations at `MANY_ZONES_LR` on the virtual
#: printer: an iteration's CPU time grows with the zones, and at 16 zones lqg_ff's 150
#: (about 2.3 CPU s each) no longer fit five minutes cold on two cores; 60 at 0.1 there:
#: 185 CPU s, 57.1 % below lambda PI, 39.4 % below the best classical design (lqg)
#: (`python experiments/printer_scale.py --zones 16 --families lqg_ff`)
MANY_ZONES = 9
MANY_ZONES_STEPS = {"lqg_ff": 60}
MANY_ZONES_LR = {"lqg_ff": 0.1}


def printer_defaults(family: str, zones: int) -> tuple[int, float | None]:
    """`(steps, lr)` of `jthermo tune` on the virtual printer with `zones` zones when no
    `--steps` is given (lr None: `tune_report`'s)."""
    if zones >= MANY_ZONES and family in MANY_ZONES_STEPS:
        return MANY_ZONES_STEPS[family], MANY_ZONES_LR.get(family)
    return SHORT_STEPS.get(family, DEFAULT_STEPS), SHORT_LR.get(family)


def add_parsers(sub) -> None:
    sp = sub.add_parser("simulate", help="closed-loop test scenarios")
    sp.add_argument("--scenario", required=True, choices=SCENARIO_KINDS)
    sp.add_argument("--controller", metavar="C", help="controller family (e.g. pi_lambda)")
    sp.add_argument("--controller-file", metavar="CTRL", help="a controller saved by `jthermo tune --out`")
    sp.add_argument("--plant", default="printer", metavar="printer|MODEL",
                    help="the virtual printer (default) or a saved model file")
    sp.add_argument("--model", metavar="MODEL",
                    help="design --controller from this saved model (default: the plant)")
    sp.add_argument("--setpoint", type=setpoints, metavar="T[,T...]",
                    help="set point, °C: one value or one per output (a fitted plant only; "
                         "default: the middle of the recorded range)")
    sp.add_argument("--powder", default=None, help="powder preset of the virtual printer")
    sp.add_argument("--zones", type=positive_int(MAX_ZONES), default=None,
                    help=f"zones of the virtual printer (default {PRINTER_ZONES})")
    sp.add_argument("--rollouts", type=positive_int(MAX_ROLLOUTS), default=8)
    sp.add_argument("--duration", type=duration, default=None, metavar="SECONDS")
    _add_printer_seed(sp, "the scenarios' disturbances and noise")
    add_common(sp)

    sp = sub.add_parser("generate", help="open-loop data from the virtual printer")
    sp.add_argument("--experiment", default="prbs", choices=("prbs", "step", "constant"))
    sp.add_argument("--zones", type=positive_int(MAX_ZONES), required=True)
    sp.add_argument("--duration", type=duration, required=True, metavar="SECONDS")
    sp.add_argument("--effects", default=None, help="comma-separated physical effects to switch on")
    sp.add_argument("--powder", default=None, help="powder preset (e.g. PA12, PA11)")
    _add_printer_seed(sp, "the record (input sequence, noise)")
    sp.add_argument("--out", required=True, metavar="DATA.csv")
    add_common(sp, plot=False)

    sp = sub.add_parser("tune", help="gradient tuning of a controller family")
    sp.add_argument("--controller", required=True, metavar="C",
                    help="family to start from: pi_lambda (alias pi), pi_untuned, pi_decoupled, "
                         "feedforward, imc, lqg, gated_pi")
    sp.add_argument("--model", metavar="MODEL", help="design from (and tune against) this saved model")
    sp.add_argument("--plant", default=None, metavar="printer|MODEL",
                    help="tune against the virtual printer or a saved model (default: --model "
                         "when given, else the printer)")
    sp.add_argument("--zones", type=positive_int(MAX_ZONES), default=None,
                    help=f"zones of the virtual printer (default {PRINTER_ZONES})")
    sp.add_argument("--powder", default=None,
                    help=f"powder preset tuned on (default {PRINTER_POWDER}); the report adds the "
                         "other one")
    sp.add_argument("--rollouts", type=positive_int(MAX_ROLLOUTS), default=16)
    sp.add_argument("--steps", type=positive_int(100000), default=None,
                    help=f"Adam iterations (default {DEFAULT_STEPS}; on the virtual printer "
                         f"{SHORT_STEPS['pi_lambda']} for pi, {SHORT_STEPS['lqg']} at learning "
                         f"rate {SHORT_LR['lqg']} for lqg, and from {MANY_ZONES} zones "
                         + ", ".join(f"{n} at {MANY_ZONES_LR.get(f, 0.05)} for {f}"
                                     for f, n in MANY_ZONES_STEPS.items()) + ")")
    sp.add_argument("--setpoint", type=setpoints, metavar="T[,T...]",
                    help="set point, °C: one value or one per output (a fitted plant only; "
                         "default: the middle of the recorded range)")
    sp.add_argument("--validation-plant", metavar="MODEL",
                    help="judge the tuned and classical designs on this model as well "
                         "(e.g. fitted to another record); never tuned on")
    sp.add_argument("--out", metavar="CTRL", help="save the tuned controller here")
    _add_printer_seed(sp, "the training and held-out rollouts")
    add_common(sp)


def _add_printer_seed(sp, seed_draws: str) -> None:
    """`--printer-seed`: which virtual printer (the same one for every command by default)."""
    sp.add_argument("--printer-seed", type=seed, default=0,
                    help="the virtual printer itself: its zone-to-zone variation (capacity, loss, "
                         "heater power) and sensor offsets (default 0, the printer every command "
                         f"uses); --seed draws {seed_draws}")


# ---------------------------------------------------------------- helpers


def _printer_seed_only_for_printer(command: str, args, own: bool) -> None:
    """`--printer-seed` (other than the default), `--zones` and `--powder` describe the virtual
    printer: with a fitted plant (`--plant MODEL`) there is none, and the option would be
    silently ignored. For the printer, unset ones take their defaults."""
    if own:
        for opt, given in (("--printer-seed", args.printer_seed != 0),
                           ("--zones", args.zones is not None),
                           ("--powder", args.powder is not None)):
            if given:
                raise ConfigError(f"{command}: {opt} is for the virtual printer, not a fitted "
                                  "plant (--plant MODEL)")
    else:
        args.zones = PRINTER_ZONES if args.zones is None else args.zones


def _plant(args):
    """`printer` or a saved model file -> (plant or 'printer' marker, description)."""
    if args.plant == "printer":
        return "printer", "printer"
    from .. import io

    input_file(args.plant, "--plant")
    return io.load_model(args.plant), str(args.plant)


def setpoints(text: str) -> list[float]:
    """`--setpoint`: one temperature or a comma-separated one per output, °C."""
    import math

    try:
        vals = [float(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected numbers in °C, got {text!r}") from None
    if not vals or not all(math.isfinite(v) for v in vals):
        raise argparse.ArgumentTypeError(f"expected finite numbers in °C, got {text!r}")
    return vals


def _own_plant(args, plant, model_file):
    """The envelope and (printed) operating point of a fitted plant (`models.operating`): the
    recording stored with the plant's file (else `model_file`'s; a stand-in without one)."""
    from .. import io
    from ..models.envelope import Envelope
    from ..models.operating import operating_point

    env = None
    for f in (args.plant, model_file):
        if f is not None and f != "printer":
            env = io.load_envelope(f)
            if env is not None:
                break
    env = (env or Envelope.from_model(plant)).check(plant)
    sp = args.setpoint
    if sp is not None and len(sp) not in (1, env.n_outputs):
        raise ConfigError(f"--setpoint: give one value or {env.n_outputs} (one per output), "
                          f"got {len(sp)}")
    op = operating_point(plant, env, sp)
    info(args, op.line())
    args.operating_point = op
    return env, op.r


def _controller_family(name: str) -> str:
    """The controller family named by `--controller` (aliases such as `pi` resolved)."""
    design = require("jthermo.control.design", "controller design")
    family = design.canonical_family(name)
    if family not in design.FAMILIES:
        raise ConfigError(f"--controller: unknown family {name!r}; choose one of "
                          + ", ".join(design.FAMILIES) + " (or " + ", ".join(design.ALIASES) + ")")
    return family


def _accepted(fn, kwargs: dict) -> dict:
    """The keyword arguments `fn` accepts (the library evolves; options it lacks are dropped
    only when they are at their defaults)."""
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return kwargs
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return kwargs
    return {k: v for k, v in kwargs.items() if k in params}


def _one_trajectory(cl, kind, controller, plant, duration, seed, scenario_kw=None) -> dict:
    """The first rollout of a scenario, for figures: `t, y, u, r` as NumPy arrays.

    `controller` is a controller module or `"untuned"` (the original identical PI per zone)."""
    import jax
    import numpy as np

    if isinstance(controller, str):
        from ..control import DiagonalPI

        controller = DiagonalPI.untuned(int(plant.n_outputs), ts=plant.ts)
    sc = cl.make_scenario(kind, plant, duration, jax.random.key(int(seed)), **(scenario_kw or {}))
    tr = cl.simulate(plant, controller, sc)
    return {"t": np.arange(sc.n_samples) * sc.ts, "y": np.asarray(tr.y), "u": np.asarray(tr.u),
            "r": np.asarray(tr.r)}


# ---------------------------------------------------------------- commands


def cmd_simulate(args: argparse.Namespace) -> dict:
    from .. import io
    from ..runtime import busy, one_thread_backend

    if busy():   # small ops in a long loop: one intra-op thread on a loaded 2-core machine
        one_thread_backend()
    if (args.controller is None) == (args.controller_file is None):
        raise ConfigError("simulate: give exactly one of --controller C or --controller-file CTRL")
    js = output_path(args.json, "--json")
    plot = plot_dir(args)
    controller: Any = args.controller
    if args.controller_file is not None:
        input_file(args.controller_file, "--controller-file")
        controller = io.load_controller(args.controller_file)
    plant, plant_desc = _plant(args)
    cl = require("jthermo.closedloop", "closed-loop simulation")
    if isinstance(controller, str):
        controller = args.controller = _controller_family(controller)
        if controller == "pi_untuned":
            controller = "untuned"
    t0 = time.perf_counter()
    if plant == "printer":
        from ..printer import make_printer

        plant = make_printer(args.zones or PRINTER_ZONES, getattr(cl, "REALISTIC_EFFECTS", ()),
                             powder=args.powder or PRINTER_POWDER, seed=args.printer_seed)
    from ..models import AbstractModel

    own = isinstance(plant, AbstractModel)
    if not own and (args.setpoint is not None or args.model is not None):
        raise ConfigError("simulate: --setpoint and --model are for a fitted plant (--plant MODEL)")
    _printer_seed_only_for_printer("simulate", args, own)
    scenario_kw: dict[str, Any] = {}
    if own:
        env, r = _own_plant(args, plant, args.model)
        scenario_kw = {"envelope": env, "setpoint": r}
    kwargs: dict[str, Any] = {"rollouts": args.rollouts, "duration": args.duration,
                              "seed": args.seed, "scenario_kw": scenario_kw}
    prepared = None
    if (not own and isinstance(controller, str) and controller not in ("untuned", *PREPARE_SKIP)
            and args.model is None):
        # the run program compiles in a thread while the printer's design model is computed
        prepared = prepare_in_background(cl, args.scenario, controller, plant, kwargs)
    if isinstance(controller, str) and controller != "untuned":
        from ..control.design import design

        if args.model is not None:
            input_file(args.model, "--model")
            model = io.load_model(args.model)
        else:
            model = plant if own else stored_printer_model(plant)
        controller = design(controller, model, **({"setpoint": r} if own else {}))
    if prepared is not None:
        prepared.join()
    out = cl.run(args.scenario, controller, plant, **_accepted(cl.run, kwargs))
    seconds = time.perf_counter() - t0
    traj = out.pop("trajectory", None) if isinstance(out, dict) else None
    if plot is not None and traj is None:
        traj = _one_trajectory(cl, args.scenario, controller, plant, args.duration, args.seed,
                               scenario_kw)
    report = {"scenario": args.scenario,
              "controller": args.controller or str(args.controller_file),
              "plant": plant_desc, "design_model": args.model,
              "zones": out.get("zones", args.zones), "rollouts": args.rollouts,
              **{k: v for k, v in out.items() if k not in ("scenario", "controller")},
              "seed": args.seed}
    if plant_desc == "printer":
        report["printer_seed"] = args.printer_seed
    if own:
        report["operating_point"] = args.operating_point.to_dict()
    report.setdefault("seconds", seconds)
    if plot is not None and traj is not None:
        from .. import plots

        plot.mkdir(parents=True, exist_ok=True)
        plots.plot_closed_loop(traj["t"], traj["y"], traj["u"], traj["r"],
                               path=plot / f"closed_loop_{args.scenario}.png")
        report["figures"] = [str(plot / f"closed_loop_{args.scenario}.png")]
    report = write_report(args, js, report)
    metrics = report.get("metrics", {})
    info(args, f"{args.scenario} / {report['controller']}: "
               + summary_line(metrics, list(metrics)[:6]))
    return report


def cmd_generate(args: argparse.Namespace) -> dict:
    out = output_path(args.out, "--out")
    js = output_path(args.json, "--json")
    distinct_outputs(out, js)
    effects = tuple(e.strip() for e in args.effects.split(",") if e.strip()) if args.effects else ()
    printer = require("jthermo.printer", "the virtual printer")
    from ..data import save_csv

    # the printer from --printer-seed, the record's draws from --seed: an estimation and a
    # validation record of one printer differ in --seed only
    kwargs = {"powder": args.powder, "seed": args.printer_seed}
    if args.powder is None:
        kwargs.pop("powder")
    p = printer.make_printer(args.zones, effects, **_accepted(printer.make_printer, kwargs))
    data = printer.generate(p, args.experiment, args.duration, seed=args.seed)
    save_csv(data, out)
    report = {"experiment": args.experiment, "zones": args.zones, "duration": args.duration,
              "effects": list(effects), "powder": args.powder, "out": str(out),
              "n_samples": data.n_samples, "ts": data.ts, "seed": args.seed,
              "printer_seed": args.printer_seed,
              "columns": ["t"] + [f"u_{n}" for n in data.input_names] + [f"y_{n}" for n in data.output_names]
              + [f"w_{n}" for n in data.signal_names]}
    report = write_report(args, js, report)
    info(args, f"wrote {out}: {data.n_samples} samples, {data.n_inputs} inputs, {data.n_outputs} outputs")
    return report


def cmd_tune(args: argparse.Namespace) -> dict:
    from .. import io
    from ..control import AbstractController

    out = output_path(args.out, "--out")
    js = output_path(args.json, "--json")
    distinct_outputs(out, js)
    plot = plot_dir(args)
    model = None
    if args.model is not None:
        input_file(args.model, "--model")
        model = io.load_model(args.model)
    if args.plant is None:   # as the help says and a tune sweep does: the model is the plant
        args.plant = "printer" if args.model is None else args.model
    plant, _ = _plant(args)
    tune = require("jthermo.tune", "tuning")
    args.controller = _controller_family(args.controller)
    from ..models import AbstractModel

    own = isinstance(plant, AbstractModel)
    if not own and (args.setpoint is not None or args.validation_plant is not None):
        raise ConfigError("tune: --setpoint and --validation-plant are for a fitted plant "
                          "(--plant MODEL)")
    _printer_seed_only_for_printer("tune", args, own)
    validation = None
    if own:
        model = plant if model is None else model
        if model.n_inputs != model.n_outputs:
            raise ConfigError(f"tune: the model has {model.n_inputs} heater(s) and {model.n_outputs} "
                              "sensor(s); the controllers need one sensor per heater: fit it on "
                              "the heated zones' sensors (`jthermo fit ... --outputs NAME[,NAME...]`)")
        env, r = _own_plant(args, plant, args.model)
        if args.validation_plant is not None:
            input_file(args.validation_plant, "--validation-plant")
            validation = io.load_model(args.validation_plant)
    lr = None
    if args.steps is None:
        args.steps, lr = (DEFAULT_STEPS, None) if own else \
            printer_defaults(args.controller, args.zones)
    bar = progress_bar(args, f"tune {args.controller}", total=args.steps)
    t0 = time.perf_counter()
    try:
        if own:
            rep = tune.tune_own_plant(args.controller, model, plant=plant, envelope=env,
                                      setpoint=r, validation_plant=validation,
                                      rollouts=args.rollouts, steps=args.steps, seed=args.seed,
                                      progress=bar)
        else:
            rep = tune.tune_report(args.controller, plant=plant, model=model,
                                   rollouts=args.rollouts, steps=args.steps, seed=args.seed,
                                   zones=args.zones, powder=args.powder or PRINTER_POWDER,
                                   progress=bar,
                                   plant_seed=args.printer_seed,
                                   train_dtype=TRAIN_DTYPE.get(args.controller),
                                   **({} if lr is None else {"lr": lr}))
    finally:
        bar.close()
    rep = dict(rep)
    ctrls = {k: v for k, v in rep.items() if isinstance(v, AbstractController)}
    for k in ctrls:
        rep.pop(k)
    costs = rep.get("costs") or rep.get("history")
    report = {"controller": args.controller, **rep, "seed": args.seed}
    if own:
        report["operating_point"] = args.operating_point.to_dict()
    report["tuned_vs_start_percent"] = _gain(report.get("start_cost"), report.get("tuned_cost"))
    if not own:
        report["printer_seed"] = args.printer_seed
    report.setdefault("seconds", time.perf_counter() - t0)
    if plot is not None and costs is not None:
        from .. import plots

        plot.mkdir(parents=True, exist_ok=True)
        plots.plot_tuning_curve(costs, path=plot / "tuning.png")
        report["figures"] = [str(plot / "tuning.png")]
    if out is not None:
        tuned = next((v for k, v in ctrls.items() if "tuned" in k), None) or next(iter(ctrls.values()), None)
        if tuned is None:
            raise ConfigError("tune: the tuning result holds no controller to save")
        io.save(tuned, out, meta={"family": args.controller, "seed": args.seed,
                                  "tuned_cost": report.get("tuned_cost"),
                                  **({"operating_point": report["operating_point"]}
                                     if own else {})})
        report["out"] = str(out)
    report = write_report(args, js, report)
    kept = " (the tuning kept its start: no step beat it on held-out rollouts)" \
        if report.get("moved") is False else ""
    info(args, f"{args.controller}: " + summary_line(
        report, ("start_cost", "tuned_cost", "tuned_vs_start_percent", "lambda_pi_cost",
                 "improvement_percent", "seconds")) + kept)
    return report


def _gain(start, tuned):
    """100 (1 - tuned / start): what the tuning itself gained over its start (the report's
    `improvement_percent` compares with the lambda PI, which for another family measures the
    family, not the tuning); None where either cost is missing or the start's is not positive."""
    if not isinstance(start, (int, float)) or not isinstance(tuned, (int, float)) or start <= 0:
        return None
    return 100.0 * (1.0 - float(tuned) / float(start))
