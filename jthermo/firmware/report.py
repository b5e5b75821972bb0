"""`calibrate`'s report: `report.md` with its figures (the fit, the step responses, the closed
loops of the tuned firmware PID and the comparison with the yardsticks), drawn with
`jthermo.plots`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import plot_closed_loop, plot_compare, plot_step
from . import tuning

#: the figures, by the name they are written under in the output folder
FIGURES = {"fit": "fit.png", "step": "step.png", "startup": "closed_loop_startup.png",
           "changes": "closed_loop_changes.png", "comparison": "comparison.png"}
#: the controllers drawn in the comparison beside the tuned PID, when there
COMPARED = ("pid_calibrate", "printer_config", "firmware_mpc", "pi_lambda")


def figures(out: Path, *, val, yhat: dict, fits: dict, models: dict, runs: dict, ts: float,
            duration: float) -> dict:
    """Write the figures into `out`; returns `{name: file name}`. `yhat`/`fits`: simulated
    outputs on the validation record and their fit %; `models`: the models whose step
    responses are drawn; `runs`: `{controller: {kind: (y, u, r)}}` on the judging plant (the
    tuned one `firmware_pid`; kinds `tracking` and `preheat`)."""
    plot_compare(val, yhat, fits, path=out / FIGURES["fit"])
    plot_step(models, max(2, round(0.5 * duration / ts)), path=out / FIGURES["step"])
    for kind, name in (("preheat", "startup"), ("tracking", "changes")):
        y, u, ref = runs["firmware_pid"][kind]
        plot_closed_loop(np.arange(y.shape[0]) * ts, y, u, ref,
                         names=[f"{i}" for i in range(y.shape[1])], path=out / FIGURES[name])
    names = ["firmware_pid", *(c for c in COMPARED if c in runs)]
    pre = [runs[c]["preheat"] for c in names]
    ys = np.concatenate([y[:, :1] for y, _, _ in pre], axis=1)
    us = np.concatenate([u[:, :1] for _, u, _ in pre], axis=1)
    plot_closed_loop(np.arange(ys.shape[0]) * ts, ys, us, pre[0][2][:, :1], names=names,
                     path=out / FIGURES["comparison"])
    return dict(FIGURES)


def verdict(table: dict, lim: dict) -> str:
    """The acceptance figures in words: the tuned PID against the floor + noise and against
    the relay PID (or, where that sits at a limit, the lambda PI)."""
    fw = table["firmware_pid"]
    bound = lim.get("tracking_bound_mse")
    parts = [f"tuned firmware PID: set-point-change MSE {fw['mse']:.3g} °C²"]
    if bound:
        parts.append(f"{100 * (fw['mse'] / bound - 1):+.0f} % against the floor + noise {bound:.3g}")
    parts.append(f"start-up overshoot {fw['overshoot_C']:.2f} °C")
    if fw["saturated_fraction"] > tuning.MAX_SATURATED:
        parts.append(f"but it sits at an input limit {100 * fw['saturated_fraction']:.0f} % of the "
                     "set-point changes on the judging plant: not a settled loop, check before use")
    cal = table.get("pid_calibrate")
    bar = "pid_calibrate"
    if cal and cal["saturated_fraction"] >= tuning.MAX_SATURATED:
        parts.append(f"the PID_CALIBRATE yardstick failed (at a limit "
                     f"{100 * cal['saturated_fraction']:.0f} % of the time)")
        bar = "pi_lambda"
    elif not cal:
        bar = "pi_lambda"
    ref = table.get(bar)
    if ref:
        pct = 100 * (1 - fw["mse"] / ref["mse"])
        side = "below" if pct >= 0 else "above"
        parts.append(f"{abs(pct):.0f} % {side} {bar}'s MSE {ref['mse']:.3g}")
        if bound and ref["mse"] < 1.25 * bound:
            parts.append(f"{bar} is itself within {100 * (ref['mse'] / bound - 1):.0f} % of the "
                         "floor + noise: 20 % below it is below the floor + noise")
    return "; ".join(parts)


def markdown(rep: dict, fw_text: str, figs: dict | None, command: str) -> str:
    """`report.md`: the finding, the model, the comparison table, the figures (each with the
    command that made it) and the firmware settings."""
    rows = [("| controller | kind | set-point MSE °C² | at a limit | start-up overshoot °C "
             "| load MSE °C² |"), "|---|---|---|---|---|---|"]
    rows += [f"| {c['name']} | {c['kind']} | {c['mse']:.4g} | {100 * c['saturated_fraction']:.0f} % "
             f"| {c['overshoot_C']:.2f} | {c['load_mse']:.4g} |" for c in rep["controllers"]]
    m = rep["model"]
    fence = "```"
    mpc = rep.get("mpc")
    bound = rep["floor_plus_noise"]
    model = (f"Model: {m['family']} {m['orders']}, {m['validation_fit_percent']:.1f} % "
             f"simulation fit on the validation record. Set point {rep['setpoints']} °C, "
             f"sample time {rep['ts']:g} s.")
    judged = (f"Judged on {rep['judged_on']}; floor + noise (no controller within the input "
              "limits does better on the set-point changes): "
              f"{'none for this plant' if bound is None else f'{bound:.4g} °C²'}. "
              f"Load step: {rep['load']['what']}.")
    lines = ["# Heater calibration", ""]
    if not rep.get("supported", True):
        lines += [f"**Not a tuning to use:** {rep['why_not']}.", ""]
    lines += [f"Diagnosis: {rep['finding']}", "",
             f"Verdict: {rep['verdict']}.", "", model, "", judged, "", *rows, ""]
    if mpc:
        c = mpc["constants"]
        text = (f"Heater power {c['heater_power']:g} W (given), block heat capacity "
                f"{c['block_heat_capacity']:.4g} J/K, sensor responsiveness "
                f"{c['sensor_responsiveness']:.4g} K/s/K, ambient transfer "
                f"{c['ambient_transfer']:.4g} W/K, with the fan at full "
                f"{c['fan_ambient_transfer']:.4g} W/K; ambient {mpc['ambient_C']:.1f} °C; "
                f"{mpc['validation_fit_percent']:.1f} % simulation fit on the validation record.")
        lines += ["## Two-state hot-end model (MPC)", "", text, ""]
    if figs:
        lines += ["## Figures", "", f"Made by `{command}`.", ""]
        caps = {"fit": "the models' simulation on the validation record",
                "step": "step responses of the design and the validation models",
                "startup": "the tuned firmware PID's start-up on the judging plant",
                "changes": "its set-point changes (and their input)",
                "comparison": "the start-up of the tuned PID, the firmware MPC and the yardsticks"}
        lines += [f"![{caps[k]}]({v})" for k, v in figs.items()] + [""]
    lines += ["## Settings", "", fence, fw_text.rstrip(), fence, ""]
    return "\n".join(lines)


__all__ = ["COMPARED", "FIGURES", "figures", "markdown", "verdict"]
