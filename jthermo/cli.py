"""The `jthermo` command: parse, check inputs up front, call the library, report.

Every command takes `--json PATH` (a JSON report written atomically), `--seed`, `--quiet`.
Errors are one line on stderr and exit status 2, never a traceback and never a partial
output file; Ctrl-C prints one line and exits with 130, leaving saved files intact.
Imports of the library are lazy (inside each command), so `jthermo --help` is fast.

    jthermo fit EST.csv --model {arx,armax,oe,bj,ss,greybox} [--orders ...] [--validation VAL.csv]
                [--common-denominator] [--rest-level T[,T...]] [--out MODEL] [--json REPORT.json]
                [--seed S] [--plot DIR]
    jthermo validate MODEL DATA.csv [--json R.json] [--plot DIR]
    jthermo simulate --scenario {tracking,powder,print,preheat,ensemble} --controller C
                [--controller-file CTRL] [--plant printer|MODEL] [--zones N] [--rollouts B]
                [--duration SECONDS] [--seed S] [--json OUT] [--plot DIR]
    jthermo generate --experiment prbs --zones N --duration SECONDS [--effects ...] --out DATA.csv
    jthermo tune --controller C [--model MODEL] [--plant printer] [--rollouts B] [--steps K]
                [--seed S] [--json OUT] [--out CTRL] [--plot DIR]
    jthermo diagnose EST.csv --validation VAL.csv --json OUT.json [--model greybox] [--seed S]
                [--report DIR]
    jthermo sweep [CONFIG.toml] [--ray ADDRESS] [--results FILE] [--summary] [--workers N]
    jthermo demo [--name NAME] [--quick]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

from .families import MODEL_FAMILIES as FAMILIES, ORDER_NAMES

EXIT_OK = 0
EXIT_ERROR = 2
EXIT_INTERRUPT = 130

SCENARIOS = ("tracking", "powder", "print", "preheat", "ensemble")
MAX_ZONES = 256
MAX_DURATION = 7 * 24 * 3600.0
MAX_ROLLOUTS = 65536
MAX_ORDER = 64


class UsageError(Exception):
    """A command-line usage error (argparse's, made one line)."""


# ---------------------------------------------------------------- argument types


def _number(text: str, cast, what: str):
    """`cast(text)`, or argparse's one-line error naming what was expected."""
    try:
        return cast(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None


def _positive_int(limit: int):
    def conv(text: str) -> int:
        v = _number(text, int, "a positive integer")
        if not 1 <= v <= limit:
            raise argparse.ArgumentTypeError(f"must lie in 1..{limit}, got {v}")
        return v

    conv.__name__ = "positive integer"
    return conv


def _seed(text: str) -> int:
    v = _number(text, int, "an integer seed")
    if not 0 <= v < 2**32:
        raise argparse.ArgumentTypeError(f"seed must lie in 0..2**32-1, got {v}")
    return v


def _duration(text: str) -> float:
    v = _number(text, float, "seconds")
    if not (math.isfinite(v) and 0 < v <= MAX_DURATION):
        raise argparse.ArgumentTypeError(f"duration must lie in (0, {MAX_DURATION:g}] s, got {text}")
    return v


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, no usage dump
        raise UsageError(f"{self.prog}: {message}")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="jthermo", description="Identify thermal models of multi-zone heated systems "
                "and tune their controllers (JAX).")
    from . import __version__

    p.add_argument("--version", action="version", version=f"jthermo {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    def common(sp, plot=True):
        sp.add_argument("--json", metavar="PATH", help="write a JSON report here (atomically)")
        sp.add_argument("--seed", type=_seed, default=0, help="random seed (default 0)")
        sp.add_argument("--quiet", action="store_true", help="no progress bars")
        if plot:
            sp.add_argument("--plot", metavar="DIR", help="write figures (PNG) into DIR")

    sp = sub.add_parser("fit", help="fit a model family to an experiment")
    sp.add_argument("data", metavar="EST.csv", help="estimation data (CSV, Parquet or .npz)")
    sp.add_argument("--model", required=True, choices=FAMILIES, help="model family")
    sp.add_argument("--orders", help="comma-separated orders in MATLAB's order: arx na,nb,nk; "
                    "armax na,nb,nc,nk; oe nb,nf,nk; bj nb,nc,nd,nf,nk; ss n (default: chosen "
                    "by the order-selection criterion)")
    sp.add_argument("--validation", metavar="VAL.csv", help="validation data (default: EST)")
    sp.add_argument("--out", metavar="MODEL", help="save the fitted model here")
    sp.add_argument("--common-denominator", action="store_true",
                    help="oe/bj: one F per output shared by its inputs (SIPPY's MIMO structure) "
                    "instead of one per input-output pair (MATLAB's)")
    sp.add_argument("--rest-level", metavar="T[,T...]",
                    help="arx/armax/oe/bj: the outputs' level at rest with zero input when known "
                    "(e.g. the measured ambient, °C; one number or one per output)")
    common(sp)

    sp = sub.add_parser("validate", help="fit %% and residual tests of a saved model on data")
    sp.add_argument("model", metavar="MODEL", help="a model saved by `jthermo fit --out`")
    sp.add_argument("data", metavar="DATA.csv")
    common(sp)

    sp = sub.add_parser("simulate", help="closed-loop test scenarios")
    sp.add_argument("--scenario", required=True, choices=SCENARIOS)
    sp.add_argument("--controller", metavar="C", help="controller family (e.g. pi_lambda)")
    sp.add_argument("--controller-file", metavar="CTRL", help="a controller saved by `jthermo tune --out`")
    sp.add_argument("--plant", default="printer", metavar="printer|MODEL",
                    help="the virtual printer (default) or a saved model file")
    sp.add_argument("--powder", default=None, help="powder preset of the virtual printer")
    sp.add_argument("--zones", type=_positive_int(MAX_ZONES), default=4)
    sp.add_argument("--rollouts", type=_positive_int(MAX_ROLLOUTS), default=8)
    sp.add_argument("--duration", type=_duration, default=None, metavar="SECONDS")
    common(sp)

    sp = sub.add_parser("generate", help="open-loop data from the virtual printer")
    sp.add_argument("--experiment", default="prbs", choices=("prbs", "step", "constant"))
    sp.add_argument("--zones", type=_positive_int(MAX_ZONES), required=True)
    sp.add_argument("--duration", type=_duration, required=True, metavar="SECONDS")
    sp.add_argument("--effects", default=None, help="comma-separated physical effects to switch on")
    sp.add_argument("--powder", default=None, help="powder preset (e.g. PA12, PA11)")
    sp.add_argument("--out", required=True, metavar="DATA.csv")
    common(sp, plot=False)

    sp = sub.add_parser("tune", help="gradient tuning of a controller family")
    sp.add_argument("--controller", required=True, metavar="C",
                    help="family to start from: pi_lambda (alias pi), pi_untuned, pi_decoupled, "
                         "feedforward, imc, lqg, gated_pi")
    sp.add_argument("--model", metavar="MODEL", help="design from (and tune against) this saved model")
    sp.add_argument("--plant", default="printer", metavar="printer|MODEL")
    sp.add_argument("--zones", type=_positive_int(MAX_ZONES), default=4,
                    help="zones of the virtual printer (default 4)")
    sp.add_argument("--powder", default="PA12",
                    help="powder preset tuned on (default PA12); the report adds the other one")
    sp.add_argument("--rollouts", type=_positive_int(MAX_ROLLOUTS), default=16)
    sp.add_argument("--steps", type=_positive_int(100000), default=150,
                    help="Adam iterations (default 150)")
    sp.add_argument("--out", metavar="CTRL", help="save the tuned controller here")
    common(sp)

    sp = sub.add_parser("diagnose", help="locate and name the physics a model left out")
    sp.add_argument("data", metavar="EST.csv")
    sp.add_argument("--validation", required=True, metavar="VAL.csv")
    sp.add_argument("--model", default="greybox", choices=("greybox",))
    sp.add_argument("--report", metavar="DIR", help="write a Markdown report with figures")
    common(sp, plot=False)

    sp = sub.add_parser("sweep", help="grid/random search over orders, controllers, weights")
    sp.add_argument("config", nargs="?", metavar="CONFIG.toml", help="sweep configuration "
                    "(default: the embedded one)")
    sp.add_argument("--ray", metavar="ADDRESS", help="run the trials on a Ray cluster "
                    "('local' starts one here)")
    sp.add_argument("--results", metavar="FILE", help="JSON-lines results file (appended, resumable)")
    sp.add_argument("--summary", action="store_true", help="print the best trials and exit")
    sp.add_argument("--top", type=_positive_int(10000), default=10)
    sp.add_argument("--workers", type=_positive_int(256), default=None,
                    help="local worker processes (default: 1, in-process)")
    common(sp, plot=False)

    sp = sub.add_parser("demo", help="the whole workflow on the virtual printer")
    sp.add_argument("--name", default="demo", help="runs/<name>/report.md")
    sp.add_argument("--quick", action="store_true", help="a shorter run")
    sp.add_argument("--runs-dir", default="runs", metavar="DIR")
    common(sp, plot=False)
    return p


# ---------------------------------------------------------------- helpers


def _err(kind: str = "config"):
    from .errors import ConfigError, DataError

    return DataError if kind == "data" else ConfigError


def _input_file(path: str, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise _err()(f"{what} {p}: no such file")
    if p.is_dir():
        raise _err()(f"{what} {p}: is a directory")
    return p


def _output_path(path: str | None, what: str) -> Path | None:
    if path is None:
        return None
    p = Path(path)
    if p.is_dir():
        raise _err()(f"{what} {p}: is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK):
        raise _err()(f"{what} {p}: cannot write into {probe}")
    return p


def _distinct_outputs(*paths: Path | None) -> None:
    seen: dict = {}
    for p in paths:
        if p is None:
            continue
        key = p.resolve()
        if key in seen:
            raise _err()(f"two outputs write the same file {p}")
        seen[key] = p


def _load_data(path: str, what: str = "data"):
    from . import data as data_mod

    _input_file(path, what)
    return data_mod.load(path)


def _same_layout(est, val, what: str = "validation") -> None:
    if (est.n_inputs, est.n_outputs, est.w.shape[1]) != (val.n_inputs, val.n_outputs, val.w.shape[1]):
        raise _err("data")(
            f"{what} data has {val.n_inputs} inputs, {val.n_outputs} outputs, {val.w.shape[1]} signals; "
            f"the estimation data has {est.n_inputs}, {est.n_outputs}, {est.w.shape[1]}")


def _parse_orders(family: str, text: str | None) -> dict | None:
    if text is None:
        return None
    names = ORDER_NAMES[family]
    if not names:
        raise _err()(f"--orders: the {family} model has no orders to set")
    parts = [s.strip() for s in text.split(",")]
    try:
        values = [int(s) for s in parts]
    except ValueError:
        raise _err()(f"--orders: expected comma-separated integers, got {text!r}") from None
    if len(values) != len(names):
        raise _err()(f"--orders: {family} takes {len(names)} orders ({','.join(names)}), got {len(values)}")
    for n, v in zip(names, values):
        low = 1 if n == "n" else 0
        if not low <= v <= MAX_ORDER:
            raise _err()(f"--orders: {n} must lie in {low}..{MAX_ORDER}, got {v}")
    return dict(zip(names, values))


def _require(module: str, what: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and (exc.name == module or module.startswith(exc.name + ".")):
            raise _err()(f"{what} is not available in this jthermo build (no module {module})") from None
        raise


def write_json(path: Path | None, report: dict) -> None:
    from .io import write_json as write

    write(path, report)


def _progress(args, desc: str, total: int | None = None):
    from .progress import Progress

    return Progress(total, desc, quiet=True if args.quiet else None)


def _plot_dir(args) -> Path | None:
    d = getattr(args, "plot", None)
    if d is None:
        return None
    p = Path(d)
    if p.exists() and not p.is_dir():
        raise _err()(f"--plot {p}: exists and is not a directory")
    _require("jthermo.plots", "--plot (figures)")
    return p


def _info(args, text: str) -> None:
    if not args.quiet:
        print(text, file=sys.stdout)


def _summary_line(report: dict, keys) -> str:
    parts = []
    for k in keys:
        v = report.get(k)
        if isinstance(v, float):
            parts.append(f"{k}={v:.4g}")
        elif v is not None:
            parts.append(f"{k}={v}")
    return "  ".join(parts)


# ---------------------------------------------------------------- commands


def cmd_fit(args) -> dict:
    family = args.model
    orders = _parse_orders(family, args.orders)
    extra = {}
    if args.common_denominator:
        if family not in ("oe", "bj"):
            raise _err()(f"--common-denominator: only for oe and bj, not {family}")
        extra["common_f"] = True
    if args.rest_level is not None:
        if family not in ("arx", "armax", "oe", "bj"):
            raise _err()(f"--rest-level: only for arx, armax, oe and bj, not {family}")
        try:
            extra["rest_level"] = [float(v) for v in args.rest_level.split(",")]
        except ValueError:
            raise _err()(f"--rest-level: expected comma-separated numbers, got {args.rest_level!r}") from None
        if len(extra["rest_level"]) == 1:
            extra["rest_level"] = extra["rest_level"][0]
    out = _output_path(args.out, "--out")
    js = _output_path(args.json, "--json")
    _distinct_outputs(out, js)
    plot = _plot_dir(args)
    est = _load_data(args.data, "estimation data")
    val = _load_data(args.validation, "validation data") if args.validation else None
    if val is not None:
        _same_layout(est, val)
    fit_mod = _require("jthermo.identify.fit", "identification (fit)")
    validate = _require("jthermo.validate", "validation")

    bar = _progress(args, f"fit {family}")
    t0 = time.perf_counter()
    try:
        res = fit_mod.fit(est, family, None if orders is None else tuple(orders.values()),
                          seed=args.seed, progress=bar, **extra)
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    target = val if val is not None else est
    cmp = validate.compare(res.model, target)
    report = {
        "model": family,
        "orders": dict(getattr(res, "orders", None) or orders or {}),
        "fit_percent": cmp["fit_percent"],
        "mean_fit_percent": cmp["mean_fit_percent"],
        "fit_on": "validation" if val is not None else "estimation",
        "seconds": getattr(res, "seconds", None) or seconds,
        "converged": bool(getattr(res, "converged", True)),
        "cost": getattr(res, "cost", None),
        "criterion_table": getattr(res, "criterion_table", None),
        "data": str(args.data),
        "validation": args.validation,
        "n_samples": est.n_samples,
        "ts": est.ts,
        "data_notes": list(est.notes) + (list(val.notes) if val is not None else []),
        "seed": args.seed,
    }
    if plot is not None:
        from . import plots

        plot.mkdir(parents=True, exist_ok=True)
        plots.plot_compare(target, {family: cmp["yhat"]}, {family: cmp["fit_percent"]},
                           path=plot / f"compare_{family}.png")
        plots.plot_step(res.model, min(600, max(50, est.n_samples // 4)), path=plot / f"step_{family}.png")
        plots.plot_pzmap(res.model, path=plot / f"pzmap_{family}.png")
        report["figures"] = sorted(str(p) for p in plot.glob(f"*_{family}.png"))
    if out is not None:
        from . import io

        io.save(res.model, out, meta={"family": family, "orders": report["orders"],
                                      "data": str(args.data), "seed": args.seed,
                                      "fit_percent": cmp["fit_percent"]})
        report["out"] = str(out)
    write_json(js, report)
    _info(args, f"{family} {report['orders']}: fit {['%.1f' % f for f in cmp['fit_percent']]} % "
                f"(mean {cmp['mean_fit_percent']:.2f} % on {report['fit_on']} data), "
                f"{report['seconds']:.1f} s")
    return report


def cmd_validate(args) -> dict:
    from . import io

    js = _output_path(args.json, "--json")
    plot = _plot_dir(args)
    _input_file(args.model, "model")
    model = io.load_model(args.model)
    data = _load_data(args.data)
    validate = _require("jthermo.validate", "validation")
    header = io.load_header(args.model)
    cmp = validate.compare(model, data)
    res = validate.residual_tests(model, data)
    keep = ("auto_pass", "cross_pass", "whiteness_pass", "independence_pass", "ljung_box_q",
            "ljung_box_p", "n_outside_auto", "n_outside_cross", "bound", "max_lag", "alpha")
    report = {
        "model": header.get("family"),
        "orders": header.get("orders") or header.get("meta", {}).get("orders"),
        "model_file": str(args.model),
        "data": str(args.data),
        "fit_percent": cmp["fit_percent"],
        "mean_fit_percent": cmp["mean_fit_percent"],
        "residual_tests": {k: res[k] for k in keep if k in res},
        "data_notes": list(data.notes),
    }
    if plot is not None:
        from . import plots

        plot.mkdir(parents=True, exist_ok=True)
        name = report["model"] or "model"
        plots.plot_compare(data, {name: cmp["yhat"]}, {name: cmp["fit_percent"]}, path=plot / "compare.png")
        plots.plot_residual_tests(res, path=plot / "residuals.png")
        report["figures"] = [str(plot / "compare.png"), str(plot / "residuals.png")]
    write_json(js, report)
    _info(args, f"fit {['%.1f' % f for f in cmp['fit_percent']]} % (mean {cmp['mean_fit_percent']:.2f} %), "
                f"residuals white: {res.get('whiteness_pass')}, independent of inputs: "
                f"{res.get('independence_pass')}")
    return report


def _plant(args, zones: int | None = None):
    """`printer` or a saved model file -> (plant or 'printer' marker, description)."""
    if args.plant == "printer":
        return "printer", "printer"
    from . import io

    _input_file(args.plant, "--plant")
    return io.load_model(args.plant), str(args.plant)


def cmd_simulate(args) -> dict:
    from . import io

    if (args.controller is None) == (args.controller_file is None):
        raise _err()("simulate: give exactly one of --controller C or --controller-file CTRL")
    js = _output_path(args.json, "--json")
    plot = _plot_dir(args)
    controller: Any = args.controller
    if args.controller_file is not None:
        _input_file(args.controller_file, "--controller-file")
        controller = io.load_controller(args.controller_file)
    plant, plant_desc = _plant(args)
    cl = _require("jthermo.closedloop", "closed-loop simulation")
    if isinstance(controller, str):
        controller = args.controller = _controller_family(controller)
        if controller == "pi_untuned":
            controller = "untuned"
    t0 = time.perf_counter()
    if plant == "printer":
        from .printer import make_printer

        plant = make_printer(args.zones, getattr(cl, "REALISTIC_EFFECTS", ()),
                             powder=args.powder or "PA12", seed=args.seed)
    if isinstance(controller, str) and controller != "untuned":
        from .control.design import design as _design
        from .models._base import AbstractModel

        model = plant if isinstance(plant, AbstractModel) else _require(
            "jthermo.tune", "the printer's design model").printer_model(plant)
        controller = _design(controller, model)
    kwargs: dict[str, Any] = dict(rollouts=args.rollouts, duration=args.duration, seed=args.seed)
    out = cl.run(args.scenario, controller, plant, **_accepted(cl.run, kwargs))
    seconds = time.perf_counter() - t0
    traj = out.pop("trajectory", None) if isinstance(out, dict) else None
    if plot is not None and traj is None:
        traj = _one_trajectory(cl, args.scenario, controller, plant, args.duration, args.seed)
    report = {"scenario": args.scenario,
              "controller": args.controller or str(args.controller_file),
              "plant": plant_desc, "zones": out.get("zones", args.zones), "rollouts": args.rollouts,
              **{k: v for k, v in out.items() if k not in ("scenario", "controller")},
              "seed": args.seed}
    report.setdefault("seconds", seconds)
    if plot is not None and traj is not None:
        from . import plots

        plot.mkdir(parents=True, exist_ok=True)
        plots.plot_closed_loop(traj["t"], traj["y"], traj["u"], traj["r"],
                               path=plot / f"closed_loop_{args.scenario}.png")
        report["figures"] = [str(plot / f"closed_loop_{args.scenario}.png")]
    write_json(js, report)
    metrics = report.get("metrics", {})
    _info(args, f"{args.scenario} / {report['controller']}: "
                + _summary_line(metrics, list(metrics)[:6]))
    return report


def _one_trajectory(cl, kind, controller, plant, duration, seed) -> dict:
    """The first rollout of a scenario, for figures: `t, y, u, r` as NumPy arrays."""
    import jax
    import numpy as np

    if isinstance(controller, str):
        controller = cl._controller_from(controller, cl._n_outputs(plant), plant.ts)
    sc = cl.make_scenario(kind, plant, duration, jax.random.key(int(seed)))
    tr = cl.simulate(plant, controller, sc)
    return {"t": np.arange(sc.n_samples) * sc.ts, "y": np.asarray(tr.y), "u": np.asarray(tr.u),
            "r": np.asarray(tr.r)}


def _accepted(fn, kwargs: dict) -> dict:
    """The keyword arguments `fn` accepts (the library evolves; options it lacks are dropped
    only when they are at their defaults)."""
    import inspect

    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return kwargs
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return kwargs
    return {k: v for k, v in kwargs.items() if k in params}


def cmd_generate(args) -> dict:
    out = _output_path(args.out, "--out")
    js = _output_path(args.json, "--json")
    _distinct_outputs(out, js)
    effects = tuple(e.strip() for e in args.effects.split(",") if e.strip()) if args.effects else ()
    printer = _require("jthermo.printer", "the virtual printer")
    from .data import save_csv

    kwargs = {"powder": args.powder, "seed": args.seed}
    if args.powder is None:
        kwargs.pop("powder")
    p = printer.make_printer(args.zones, effects, **_accepted(printer.make_printer, kwargs))
    data = printer.generate(p, args.experiment, args.duration, seed=args.seed)
    save_csv(data, out)
    report = {"experiment": args.experiment, "zones": args.zones, "duration": args.duration,
              "effects": list(effects), "powder": args.powder, "out": str(out),
              "n_samples": data.n_samples, "ts": data.ts, "seed": args.seed,
              "columns": ["t"] + [f"u_{n}" for n in data.input_names] + [f"y_{n}" for n in data.output_names]
              + [f"w_{n}" for n in data.signal_names]}
    write_json(js, report)
    _info(args, f"wrote {out}: {data.n_samples} samples, {data.n_inputs} inputs, {data.n_outputs} outputs")
    return report


def _controller_family(name: str) -> str:
    """The controller family named by `--controller` (aliases such as `pi` resolved)."""
    design = _require("jthermo.control.design", "controller design")
    family = design.canonical_family(name)
    if family not in design.FAMILIES:
        raise _err()(f"--controller: unknown family {name!r}; choose one of "
                     + ", ".join(design.FAMILIES) + " (or " + ", ".join(design.ALIASES) + ")")
    return family


def cmd_tune(args) -> dict:
    from . import io
    from .control._base import AbstractController

    out = _output_path(args.out, "--out")
    js = _output_path(args.json, "--json")
    _distinct_outputs(out, js)
    plot = _plot_dir(args)
    model = None
    if args.model is not None:
        _input_file(args.model, "--model")
        model = io.load_model(args.model)
    plant, _ = _plant(args)
    tune = _require("jthermo.tune", "tuning")
    args.controller = _controller_family(args.controller)
    bar = _progress(args, f"tune {args.controller}", total=args.steps)
    t0 = time.perf_counter()
    try:
        rep = tune.tune_report(args.controller, plant=plant, model=model, rollouts=args.rollouts,
                               steps=args.steps, seed=args.seed, zones=args.zones,
                               powder=args.powder, progress=bar)
    finally:
        bar.close()
    rep = dict(rep)
    ctrls = {k: v for k, v in rep.items() if isinstance(v, AbstractController)}
    for k in ctrls:
        rep.pop(k)
    costs = rep.get("costs") or rep.get("history")
    report = {"controller": args.controller, **rep, "seed": args.seed}
    report.setdefault("seconds", time.perf_counter() - t0)
    if plot is not None and costs is not None:
        from . import plots

        plot.mkdir(parents=True, exist_ok=True)
        plots.plot_tuning_curve(costs, path=plot / "tuning.png")
        report["figures"] = [str(plot / "tuning.png")]
    if out is not None:
        tuned = next((v for k, v in ctrls.items() if "tuned" in k), None) or next(iter(ctrls.values()), None)
        if tuned is None:
            raise _err()("tune: the tuning result holds no controller to save")
        io.save(tuned, out, meta={"family": args.controller, "seed": args.seed,
                                  "tuned_cost": report.get("tuned_cost")})
        report["out"] = str(out)
    write_json(js, report)
    _info(args, f"{args.controller}: " + _summary_line(
        report, ("start_cost", "tuned_cost", "lambda_pi_cost", "improvement_percent", "seconds")))
    return report


def cmd_diagnose(args) -> dict:
    js = _output_path(args.json, "--json")
    if args.report is not None and Path(args.report).exists() and not Path(args.report).is_dir():
        raise _err()(f"--report {args.report}: exists and is not a directory")
    est = _load_data(args.data, "estimation data")
    val = _load_data(args.validation, "validation data")
    _same_layout(est, val)
    diag = _require("jthermo.diagnose", "diagnosis")
    if not hasattr(diag, "diagnose"):
        raise _err()("diagnosis is not available in this jthermo build")
    if args.report is not None and not hasattr(diag, "write_report"):
        raise _err()("--report: the diagnosis report writer is not available in this jthermo build")
    bar = _progress(args, "diagnose")
    t0 = time.perf_counter()
    try:
        result = diag.diagnose(est, val, seed=args.seed, progress=bar)
    finally:
        bar.close()
    result = dict(result)
    result.setdefault("seconds", time.perf_counter() - t0)
    if args.report is not None:
        written = diag.write_report(result, args.report, est, val)
        result["report"] = str(written) if written is not None else str(Path(args.report) / "report.md")
    if hasattr(diag, "to_json"):
        result = diag.to_json(result)
    result = {k: v for k, v in result.items() if not str(k).startswith("_")}
    write_json(js, result)
    names = [f.get("mechanism") for f in result.get("findings", [])]
    _info(args, f"verdict: {result.get('verdict')}" + (f"; findings: {', '.join(map(str, names))}" if names else ""))
    return result


def cmd_sweep(args) -> dict:
    from . import sweep

    js = _output_path(args.json, "--json")
    if args.config is not None:
        _input_file(args.config, "sweep config")
        config = sweep.load_config(args.config)
    else:
        config = sweep.default_config()
    results = Path(args.results) if args.results else sweep.default_results_path(config)
    _output_path(str(results), "--results")
    if args.summary:
        rows = sweep.read_results(results)
        best = sweep.best_trials(rows, config, top=args.top)
        print(sweep.format_summary(best, config, total=len(rows)))
        report = {"results": str(results), "n_trials": len(rows), "best": best}
        write_json(js, report)
        return report
    bar = _progress(args, f"sweep {config['name']}")
    try:
        report = sweep.run_sweep(config, results, ray_address=args.ray, workers=args.workers,
                                 progress=bar)
    finally:
        bar.close()
    write_json(js, report)
    _info(args, f"sweep {config['name']}: {report['n_run']} trials run, {report['n_skipped']} already done, "
                f"{report['n_failed']} failed; results in {results}")
    if report.get("best"):
        _info(args, sweep.format_summary(report["best"], config, total=report["n_total"]))
    return report


def cmd_demo(args) -> dict:
    from . import demo

    js = _output_path(args.json, "--json")
    if not args.name or "/" in args.name or args.name in (".", ".."):
        raise _err()(f"--name: expected a plain directory name, got {args.name!r}")
    report = demo.run_demo(name=args.name, quick=args.quick, seed=args.seed,
                           runs_dir=args.runs_dir, quiet=args.quiet)
    write_json(js, report)
    _info(args, f"report: {report['report']}")
    return report


COMMANDS = {"fit": cmd_fit, "validate": cmd_validate, "simulate": cmd_simulate,
            "generate": cmd_generate, "tune": cmd_tune, "diagnose": cmd_diagnose,
            "sweep": cmd_sweep, "demo": cmd_demo}


# ---------------------------------------------------------------- entry point


def _one_line(text: str, limit: int = 400) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def _fail(message: str) -> int:
    print(_one_line(f"jthermo: error: {message}"), file=sys.stderr)
    return EXIT_ERROR


def main(argv: list[str] | None = None) -> int:
    """Run the `jthermo` command with `argv` (default `sys.argv[1:]`); returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except UsageError as exc:
        return _fail(str(exc))
    except SystemExit as exc:  # --help / --version
        return int(exc.code or 0) if not isinstance(exc.code, str) else _fail(exc.code)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_ERROR
    debug = bool(os.environ.get("JTHERMO_DEBUG"))
    try:
        with warnings.catch_warnings():
            if not debug:
                warnings.simplefilter("ignore")
            import jax

            jax.config.update("jax_enable_x64", True)
            if args.quiet:
                from .progress import set_quiet

                set_quiet(True)
            COMMANDS[args.command](args)
    except KeyboardInterrupt:
        print("jthermo: interrupted (saved files are intact)", file=sys.stderr)
        return EXIT_INTERRUPT
    except BaseException as exc:  # noqa: BLE001 - the contract: one line, status 2
        from .errors import JThermoError

        if isinstance(exc, SystemExit):
            return int(exc.code) if isinstance(exc.code, int) else EXIT_ERROR
        if debug:
            raise
        if isinstance(exc, JThermoError):
            return _fail(str(exc))
        if isinstance(exc, MemoryError):
            return _fail("out of memory (try fewer rollouts, zones or a shorter duration)")
        if isinstance(exc, OSError) and exc.filename is not None:
            return _fail(f"{exc.filename}: {exc.strerror}")
        return _fail(f"internal error ({type(exc).__name__}): {exc}")
    finally:
        if args.command is not None and getattr(args, "quiet", False):
            from .progress import set_quiet

            set_quiet(False)
    return EXIT_OK


def entry() -> None:  # pragma: no cover - console script wrapper
    sys.exit(main())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
