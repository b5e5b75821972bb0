"""`jthermo fit` and `jthermo validate`: identify a model family on data, check a saved model."""

from __future__ import annotations

import argparse
import sys
import time

from ..errors import ConfigError
from ..families import MODEL_FAMILIES, ORDER_NAMES
from .common import (
    MAX_ORDER,
    add_common,
    distinct_outputs,
    info,
    input_file,
    load_data,
    output_path,
    plot_dir,
    progress_bar,
    require,
    same_layout,
    write_report,
)


def add_parsers(sub) -> None:
    sp = sub.add_parser("fit", help="fit a model family to an experiment")
    sp.add_argument("data", metavar="EST.csv", help="estimation data (CSV, Parquet or .npz)")
    sp.add_argument("--model", required=True, choices=MODEL_FAMILIES, help="model family")
    sp.add_argument("--orders", help="comma-separated orders in MATLAB's order: arx na,nb,nk; "
                    "armax na,nb,nc,nk; oe nb,nf,nk; bj nb,nc,nd,nf,nk; ss n (default: chosen "
                    "by the order-selection criterion)")
    sp.add_argument("--validation", metavar="VAL.csv", help="validation data (default: EST)")
    sp.add_argument("--outputs", metavar="NAME[,NAME...]",
                    help="fit only these output columns (e.g. T1 of a one-heater device that "
                    "logs two sensors; default: all); validate picks them again")
    sp.add_argument("--out", metavar="MODEL", help="save the fitted model here")
    sp.add_argument("--common-denominator", action="store_true",
                    help="oe/bj: one F per output shared by its inputs (SIPPY's MIMO structure) "
                    "instead of one per input-output pair (MATLAB's)")
    sp.add_argument("--engine", choices=("auto", "jax", "numpy"),
                    help="armax/oe/bj: the PEM solver: auto (default: NumPy for problems up to "
                    "a measured size or on one core, else compiled), jax (compiled: pays its "
                    "compilation, then uses every core) or numpy (nothing compiled, one core; "
                    "diagonal A)")
    sp.add_argument("--physics", choices=("heat", "none"), default="heat",
                    help="heat (default: inputs are heat commands, outputs temperatures; the "
                    "model is stable, no heater lowers a sensor's steady temperature, no "
                    "inverse step response; a logged set point, a w_ column whose name holds "
                    "target, setpoint or set_point, is left out: neither an input nor a "
                    "disturbance) or none (any linear system, every column as given)")
    sp.add_argument("--rest-level", metavar="T[,T...]",
                    help="arx/armax/oe/bj: the outputs' level at rest with zero input when known "
                    "(e.g. the measured ambient, °C; one number or one per output)")
    add_common(sp)

    sp = sub.add_parser("validate", help="fit %% and residual tests of a saved model on data")
    sp.add_argument("model", metavar="MODEL", help="a model saved by `jthermo fit --out`")
    sp.add_argument("data", metavar="DATA.csv")
    add_common(sp)


def _parse_orders(family: str, text: str | None) -> dict | None:
    if text is None:
        return None
    names = ORDER_NAMES[family]
    if not names:
        raise ConfigError(f"--orders: the {family} model has no orders to set")
    parts = [s.strip() for s in text.split(",")]
    try:
        values = [int(s) for s in parts]
    except ValueError:
        raise ConfigError(f"--orders: expected comma-separated integers, got {text!r}") from None
    if len(values) != len(names):
        raise ConfigError(f"--orders: {family} takes {len(names)} orders ({','.join(names)}), got {len(values)}")
    for n, v in zip(names, values):
        low = 1 if n == "n" else 0
        if not low <= v <= MAX_ORDER:
            raise ConfigError(f"--orders: {n} must lie in {low}..{MAX_ORDER}, got {v}")
    return dict(zip(names, values))


def _fit_options(args) -> dict:
    """The fitter's keyword options from `--common-denominator`, `--engine` and `--rest-level`."""
    family = args.model
    extra = {}
    if args.common_denominator:
        if family not in ("oe", "bj"):
            raise ConfigError(f"--common-denominator: only for oe and bj, not {family}")
        extra["common_f"] = True
    if args.engine is not None:
        if family not in ("armax", "oe", "bj"):
            raise ConfigError(f"--engine: only for armax, oe and bj, not {family}")
        extra["engine"] = args.engine
    if args.rest_level is not None:
        if family not in ("arx", "armax", "oe", "bj"):
            raise ConfigError(f"--rest-level: only for arx, armax, oe and bj, not {family}")
        try:
            extra["rest_level"] = [float(v) for v in args.rest_level.split(",")]
        except ValueError:
            raise ConfigError(f"--rest-level: expected comma-separated numbers, got {args.rest_level!r}") from None
        if len(extra["rest_level"]) == 1:
            extra["rest_level"] = extra["rest_level"][0]
    return extra


def _leave_out_idle_inputs(est, val):
    """`(est, val, names)`: the records without the inputs constant in the estimation record (a
    logged heater never switched on), where at least one input varies; a left-out input that
    varies in `val` is refused (`data.keep_inputs`). With none varying, `fit` refuses the record."""
    from ..data import idle_inputs, keep_inputs

    idle = idle_inputs(est)
    if not idle or len(idle) == est.n_inputs:
        return est, val, []
    kept = [n for j, n in enumerate(est.input_names) if j not in idle]
    val = None if val is None else keep_inputs(val, kept, "validation data")
    return keep_inputs(est, kept, "estimation data"), val, [est.input_names[j] for j in idle]


def _model_columns(data, model, meta: dict):
    """`data` with the model's own inputs and outputs where the record has more (`fit` left out
    inputs constant in its record, or kept `--outputs`), by the names in the model's header."""
    from ..data import keep_inputs, keep_outputs

    ins, outs, sig = meta.get("inputs"), meta.get("outputs"), meta.get("signals")
    if sig is not None and list(data.signal_names) != list(sig) \
            and all(n in data.signal_names for n in sig):
        keep = [data.signal_names.index(n) for n in sig]
        data = data.replace(w=data.w[:, keep], signal_names=tuple(sig))
    if outs and len(outs) == model.n_outputs and data.n_outputs > model.n_outputs:
        data = keep_outputs(data, outs)
    if ins and len(ins) == model.n_inputs and data.n_inputs > model.n_inputs:
        data = keep_inputs(data, ins)
    return data


def cmd_fit(args: argparse.Namespace) -> dict:
    from .. import io

    family = args.model
    orders = _parse_orders(family, args.orders)
    extra = _fit_options(args)
    out = output_path(args.out, "--out")
    js = output_path(args.json, "--json")
    distinct_outputs(out, js)
    plot = plot_dir(args)
    est = load_data(args.data, "estimation data")
    val = load_data(args.validation, "validation data") if args.validation else None
    if val is not None:
        same_layout(est, val)
    if args.outputs is not None:
        from ..data import keep_outputs

        names = [n.strip() for n in args.outputs.split(",")]
        est = keep_outputs(est, names, "--outputs")
        val = None if val is None else keep_outputs(val, names, "--outputs (validation data)")
    signals_dropped = []
    if args.physics == "heat":
        from ..identify.heat import heat_data

        est, left = heat_data(est)
        signals_dropped = left["dropped_signals"]
        if val is not None and signals_dropped:
            keep = [j for j, n in enumerate(val.signal_names) if n not in signals_dropped]
            val = val.replace(w=val.w[:, keep], signal_names=tuple(val.signal_names[j] for j in keep))
        if left["dropped_inputs"]:      # the same inputs left out of the validation record
            from ..data import keep_inputs

            val = None if val is None else keep_inputs(val, est.input_names, "validation data")
    else:
        left = {"dropped_inputs": []}
    est, val, dropped = _leave_out_idle_inputs(est, val)
    dropped = left["dropped_inputs"] + dropped
    fit_mod = require("jthermo.identify.fit", "identification (fit)")
    validate = require("jthermo.validate", "validation")

    bar = progress_bar(args, f"fit {family}")
    t0 = time.perf_counter()
    try:
        res = fit_mod.fit(est, family, None if orders is None else tuple(orders.values()),
                          seed=args.seed, progress=bar, physics=args.physics, **extra)
    finally:
        bar.close()
    seconds = time.perf_counter() - t0
    target = val if val is not None else est
    cmp = validate.compare(res.model, target)
    physics = (getattr(res, "extra", None) or {}).get("physics")
    if physics is not None and left.get("rest_samples"):     # the rest put before a step test
        physics = {**physics, "rest_samples": left["rest_samples"],
                   "path": [f"step from rest: {left['rest_samples']} samples of rest put before "
                            "the record", *physics["path"]]}
    if physics is not None:
        plausible = {"warnings": physics["warnings"]}
    else:
        plausible = require("jthermo.validate.plausibility", "validation").check_fit(
            res.model, getattr(res, "envelope", None), input_names=est.input_names,
            output_names=est.output_names)
    report = {
        "model": family,
        "orders": dict(getattr(res, "orders", None) or orders or {}),
        "fit_percent": cmp["fit_percent"],
        "mean_fit_percent": cmp["mean_fit_percent"],
        "fit_on": "validation" if val is not None else "estimation",
        "seconds": getattr(res, "seconds", None) or seconds,
        "converged": bool(getattr(res, "converged", True)),
        # armax/oe/bj: the PEM engine that ran (`--engine auto` decides by the problem's size)
        "engine": (getattr(res, "extra", None) or {}).get("engine"),
        # per output (PEM families): converged, and the relative cost decrease the Gauss-Newton
        # step from the result would still give (converged below 1e-4)
        "converged_outputs": (getattr(res, "extra", None) or {}).get("row_converged"),
        "expected_improvement": (getattr(res, "extra", None) or {}).get("expected_improvement"),
        "cost": getattr(res, "cost", None),
        "criterion_table": getattr(res, "criterion_table", None),
        "checks": (getattr(res, "extra", None) or {}).get("check"),
        "repaired": (getattr(res, "extra", None) or {}).get("repaired"),
        "warnings": plausible["warnings"],
        "level_offsets": validate.level_offsets(target.y, cmp["yhat"], target.output_names),
        "data": str(args.data),
        "validation": args.validation,
        "n_samples": est.n_samples,
        "ts": est.ts,
        "data_notes": list(est.notes) + (list(val.notes) if val is not None else []),
        "inputs": list(est.input_names),
        "dropped_inputs": dropped,
        "signals": list(est.signal_names),
        "dropped_signals": signals_dropped,
        # the heat path: each candidate tried, why it was kept or passed over, the verdict
        "physics": physics,
        "outputs": list(est.output_names),
        "seed": args.seed,
    }
    if plot is not None:
        from .. import plots

        plot.mkdir(parents=True, exist_ok=True)
        plots.plot_compare(target, {family: cmp["yhat"]}, {family: cmp["fit_percent"]},
                           path=plot / f"compare_{family}.png")
        plots.plot_step(res.model, min(600, max(50, est.n_samples // 4)), path=plot / f"step_{family}.png")
        plots.plot_pzmap(res.model, path=plot / f"pzmap_{family}.png")
        report["figures"] = sorted(str(p) for p in plot.glob(f"*_{family}.png"))
    if out is not None:
        io.save(res.model, out, meta={"family": family, "orders": report["orders"],
                                      "data": str(args.data), "seed": args.seed,
                                      "inputs": list(est.input_names),
                                      "outputs": list(est.output_names),
                                      "signals": list(est.signal_names),
                                      "physics": args.physics,
                                      "fit_percent": cmp["fit_percent"],
                                      **({"envelope": res.envelope.to_dict()}
                                         if getattr(res, "envelope", None) else {})})
        report["out"] = str(out)
    report = write_report(args, js, report)
    for w in report["warnings"]:     # physically implausible, not fatal: the fit stands
        print(f"warning: {w}", file=sys.stderr)
    if signals_dropped:
        print(f"note: {', '.join('w_' + n for n in signals_dropped)}: a logged set point, left "
              "out of the model (neither an input nor a disturbance of the plant)", file=sys.stderr)
    if physics is not None and physics.get("rest_samples"):
        print(f"note: every input is constant and the record starts at rest: a step from rest, "
              f"{physics['rest_samples']} samples of rest (heaters off) put before it",
              file=sys.stderr)
    if dropped:
        print(f"warning: {', '.join('u_' + n for n in dropped)} constant in the record: left out "
              "of the model (a constant input's effect cannot be told from the level)", file=sys.stderr)
    for n in validate.level_offset_notes(report["level_offsets"]):
        print(f"note: on the {report['fit_on']} data, {n}", file=sys.stderr)
    info(args, f"{family} {report['orders']}: fit {[f'{f:.1f}' for f in cmp['fit_percent']]} % "
               f"(mean {cmp['mean_fit_percent']:.2f} % on {report['fit_on']} data), "
               f"{report['seconds']:.1f} s")
    rows = report["converged_outputs"] or []
    if not all(rows):
        gains = report["expected_improvement"]
        info(args, "not converged on output(s) " + ", ".join(
            f"{i + 1} (a Gauss-Newton step would lower its cost by {100 * gains[i]:.3g} %)"
            for i, ok in enumerate(rows) if not ok))
    return report


def cmd_validate(args: argparse.Namespace) -> dict:
    from .. import io

    js = output_path(args.json, "--json")
    plot = plot_dir(args)
    input_file(args.model, "model")
    model = io.load_model(args.model)
    data = load_data(args.data)
    validate = require("jthermo.validate", "validation")
    header = io.load_header(args.model)
    data = _model_columns(data, model, header.get("meta") or {})
    cmp = validate.compare(model, data)
    res = validate.residual_tests(model, data)
    keep = ("auto_pass", "cross_pass", "whiteness_pass", "independence_pass", "constant_inputs",
            "ljung_box_q", "ljung_box_p", "n_outside_auto", "n_outside_cross", "bound", "max_lag",
            "alpha")
    report = {
        "model": header.get("family"),
        "orders": header.get("orders") or header.get("meta", {}).get("orders"),
        "model_file": str(args.model),
        "data": str(args.data),
        "fit_percent": cmp["fit_percent"],
        "mean_fit_percent": cmp["mean_fit_percent"],
        "residual_tests": {k: res[k] for k in keep if k in res},
        "level_offsets": validate.level_offsets(data.y, cmp["yhat"], data.output_names),
        "data_notes": list(data.notes),
    }
    if plot is not None:
        from .. import plots

        plot.mkdir(parents=True, exist_ok=True)
        name = report["model"] or "model"
        plots.plot_compare(data, {name: cmp["yhat"]}, {name: cmp["fit_percent"]}, path=plot / "compare.png")
        plots.plot_residual_tests(res, path=plot / "residuals.png")
        report["figures"] = [str(plot / "compare.png"), str(plot / "residuals.png")]
    report = write_report(args, js, report)
    for n in validate.level_offset_notes(report["level_offsets"]):
        print(f"note: {n}", file=sys.stderr)
    indep, still = res.get("independence_pass"), res.get("constant_inputs") or []
    indep = ("not testable (every input constant)" if indep is None else str(indep)
             + (f" (constant, not judged: {', '.join('u_' + n for n in still)})" if still else ""))
    info(args, f"fit {[f'{f:.1f}' for f in cmp['fit_percent']]} % (mean {cmp['mean_fit_percent']:.2f} %), "
               f"residuals white: {res.get('whiteness_pass')}, independent of inputs: {indep}")
    return report
