"""`jthermo diagnose`: locate and name the physics a model left out."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

from ..errors import ConfigError
from .common import (
    add_common,
    distinct_outputs,
    info,
    load_data,
    output_path,
    progress_bar,
    require,
    same_layout,
    write_report,
)


def add_parsers(sub) -> None:
    sp = sub.add_parser("diagnose", help="locate and name the physics a model left out")
    sp.add_argument("data", metavar="EST.csv", nargs="+",
                    help="estimation record(s) of one plant: several are fitted jointly (pooled evidence)")
    sp.add_argument("--validation", required=True, metavar="VAL.csv")
    sp.add_argument("--model", default="greybox", choices=("greybox",))
    sp.add_argument("--report", metavar="DIR", help="write a Markdown report with figures")
    sp.add_argument("--actuator", default="any", choices=("any", "resistive-pwm"),
                    help="declared actuator: findings that contradict it are flagged, not named")
    sp.add_argument("--design-experiment", metavar="OUT.csv",
                    help="when a finding is uncertain, write the input that best separates it from its "
                         "rivals (data format); otherwise say that no experiment is needed and write nothing")
    sp.add_argument("--design-duration", type=float, metavar="S",
                    help="designed record's length in s (default: the (longest) estimation record's)")
    sp.add_argument("--design-hold", type=float, default=10.0, metavar="S",
                    help="designed input's minimum switching time in s (default 10)")
    sp.add_argument("--design-max-temp", type=float, metavar="C",
                    help="highest temperature any rival model may predict on the designed input "
                         "(default: the highest recorded in the two records; raised per output to what "
                         "holding the mean input, where the design starts, reaches)")
    add_common(sp, plot=False)


def cmd_diagnose(args: argparse.Namespace) -> dict:
    js = output_path(args.json, "--json")
    design = output_path(args.design_experiment, "--design-experiment")
    distinct_outputs(js, design)
    if args.report is not None and Path(args.report).exists() and not Path(args.report).is_dir():
        raise ConfigError(f"--report {args.report}: exists and is not a directory")
    ests = [load_data(p, "estimation data") for p in args.data]
    val = load_data(args.validation, "validation data")
    for j, e in enumerate(ests):
        same_layout(e, val)
        if j:
            same_layout(ests[0], e, f"estimation record {j + 1} ({args.data[j]})")
    est = ests[0] if len(ests) == 1 else ests
    sizes = _design_samples(args, float(ests[0].ts)) if design is not None else None
    diag = require("jthermo.diagnose", "diagnosis")
    if not hasattr(diag, "diagnose"):
        raise ConfigError("diagnosis is not available in this jthermo build")
    if args.report is not None and not hasattr(diag, "write_report"):
        raise ConfigError("--report: the diagnosis report writer is not available in this jthermo build")
    bar = progress_bar(args, "diagnose")
    t0 = time.perf_counter()
    try:
        result = diag.diagnose(est, val, seed=args.seed, progress=bar, actuator=args.actuator)
    finally:
        bar.close()
    result = dict(result)
    result.setdefault("seconds", time.perf_counter() - t0)
    step = _next_step(result)
    if design is not None and step["experiment_needed"]:
        result["experiment"] = _design(result, est, val, args, design, *sizes)
    elif design is not None:
        info(args, f"{step['why']}; wrote nothing to {design}")
    result["next_step"] = step
    if args.report is not None:
        written = diag.write_report(result, args.report, est, val)
        result["report"] = str(written) if written is not None else str(Path(args.report) / "report.md")
    if hasattr(diag, "to_json"):
        result = diag.to_json(result)
    result = {k: v for k, v in result.items() if not str(k).startswith("_")}
    result = write_report(args, js, result)
    findings = result.get("findings", [])
    names = [_finding_label(f) for f in findings]
    info(args, f"verdict: {result.get('verdict')}" + (f"; findings: {', '.join(names)}" if names else ""))
    info(args, "next: " + _what_next(args, step, result.get("experiment")))
    return result


def _next_step(result: dict) -> dict:
    """`diagnose.next_step` (a stand-in diagnosis without it: any uncertain or tied finding)."""
    try:
        from ..diagnose.loop import next_step
    except ImportError:        # a build without the loop
        tied = [f for f in result.get("findings", []) if f.get("uncertain") or f.get("rivals")]
        return {"experiment_needed": bool(tied), "rivals": [], "why": "an uncertain finding"}
    return next_step(result)


def _what_next(args, step: dict, exp: dict | None) -> str:
    """The summary line's advice: what the user does next."""
    if not step["experiment_needed"]:
        return step["why"]
    if exp is not None:
        more = " ".join(args.data)
        return (f"{step['why']}: run the inputs of {exp['path']} on the plant, then pool the measured "
                f"record with the others: jthermo diagnose {more} MEASURED.csv --validation {args.validation}")
    return (f"{step['why']}: --design-experiment OUT.csv designs the record that separates them "
            "(pool its measurement with these records)")


def _finding_label(f: dict) -> str:
    """A finding as the summary line names it: its mechanism, whether it is uncertain (with the
    rivals the records do not separate it from) and whether its effect is below the sensor noise."""
    notes = []
    if f.get("uncertain"):
        notes.append("uncertain" + (f", or {' / '.join(f['rivals'])}" if f.get("rivals") else ""))
    if f.get("below_noise"):
        notes.append("effect below the sensor noise")
    return f"{f.get('mechanism')}" + (f" ({'; '.join(notes)})" if notes else "")


def _design_samples(args, ts: float) -> tuple[int | None, int]:
    """(duration, hold) of the designed record in samples, from the options in s."""
    for what, v in (("--design-duration", args.design_duration), ("--design-hold", args.design_hold)):
        if v is not None and not v > 0:
            raise ConfigError(f"{what} must be positive, got {v:g}")
    if args.design_max_temp is not None and not math.isfinite(args.design_max_temp):
        raise ConfigError(f"--design-max-temp must be a finite temperature, got {args.design_max_temp:g}")
    duration = None if args.design_duration is None else max(1, round(args.design_duration / ts))
    hold = max(1, round(args.design_hold / ts))
    if duration is not None and duration < 2 * hold:
        # said before the diagnosis runs, not after it
        raise ConfigError(f"--design-duration {args.design_duration:g} s must cover at least two "
                          f"--design-hold ({args.design_hold:g} s) switching times")
    return duration, hold


def _design(result, est, val, args, path, duration, hold) -> dict:
    """Design the separating experiment, write it as a record, return its JSON summary."""
    from ..data import save_csv
    from ..diagnose import experiment

    y_max = args.design_max_temp
    if y_max is None:
        import numpy as np

        recs = est if isinstance(est, list) else [est]
        y_max = np.max(np.concatenate([np.asarray(d.y, float) for d in recs + [val]]), axis=0)
    d = experiment.design_experiment(result, est, val, duration=duration, hold=hold, seed=args.seed, y_max=y_max)
    save_csv(d["record"], path)
    js = experiment.to_json(d, path)
    info(args, f"designed experiment ({js['why']}): {' vs '.join(js['rivals'])}, separation "
               f"{js['separation_designed']:.3g} (PRBS {js['separation_prbs']:.3g}), highest predicted "
               f"{max(js['max_predicted']):.1f} °C (limit {max(js['y_max']):.1f}"
               f"{'' if js['within_y_max'] else ', exceeded: no input within the limits found'}), wrote {path}")
    return js
