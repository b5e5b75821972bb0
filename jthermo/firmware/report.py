"""`calibrate`'s report: `report.md` with its figures (the fit, the step responses, the closed
loops of the tuned firmware PID and the comparison with the yardsticks), drawn with
`jthermo.plots`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..plots import plot_closed_loop, plot_compare, plot_step

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


__all__ = ["COMPARED", "FIGURES", "figures", "markdown"]
