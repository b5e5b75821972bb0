"""`calibrate`: from a heater's record to the PID settings its firmware runs.

1. **Records.** The estimation record (e.g. a `jthermo import` segment); a logged set point
   (`w_*_target*`) is neither an input nor an output and is left out of the fit, but gives the
   default set point (the most common non-zero target). Without a validation record the last
   `HOLD_BACK` of the estimation record is held back.
2. **Model.** Each family of `FAMILIES` is fitted with the public fit API; the one with the
   best simulation fit on the validation record is the design model. The same family fitted to
   the validation record is the cross-record plant every controller is judged on.
3. **Controllers.** The firmware PID (`pid.KlipperPID`: Klipper's law at the record's sample
   time, its derivative smoothing, integral clamp and `max_power`) is tuned on the design
   model with the own-plant tuning (`tune.tune_own_plant`), starting from the relay /
   Ziegler–Nichols design detuned to the recording's noise; its gains are rounded as
   `printer.cfg` takes them before it is judged. Yardsticks, each under Klipper's law: the
   gains `PID_CALIBRATE` computes on the same model (`pid.pid_calibrate`) and the gains the
   printer ran with (from the import's summary); the model-based controllers (`MODEL_BASED`,
   designed on the design model) and the lambda PI are judged beside them.
4. **Judgement** on the cross-record plant: the set-point changes' MSE, the time at an input
   limit, the start-up overshoot, the load step's MSE, and what no controller beats, the
   full-power floor plus the noise (`tune.own.limits`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from .. import data as data_mod
from ..closedloop import metrics, model_duration, model_scenario
from ..closedloop import rollouts as run_rollouts
from ..control.design import design, design_point
from ..errors import ConfigError, ControlError, JThermoError
from ..models.envelope import Envelope, check_reachable, equilibrium_input
from ..tune.own import limits, tune_own_plant, tuning_start
from . import klippy, settings
from .pid import KlipperPID, from_standard, pid_calibrate

#: the model families tried, cheapest first
FAMILIES = ("arx", "oe")
#: share of the estimation record held back for validation when there is no validation record
HOLD_BACK = 0.3
#: model-based controllers designed on the design model and judged beside the PID
MODEL_BASED = ("imc", "lqg")
#: tuning defaults of the command (cheap; `--steps`, `--rollouts` for more)
STEPS, ROLLOUTS = 60, 4


def _heater_names(d: data_mod.IOData) -> list[str]:
    """Heater names of the outputs: `extruder_C` (the converted logs' unit suffix) -> `extruder`."""
    return [n[:-2] if n.endswith("_C") else n for n in d.output_names]


def _prepare(d: data_mod.IOData, heater: str | None, what: str):
    """Leave out logged set points; keep one heater's output and input when asked."""
    targets = [i for i, n in enumerate(d.signal_names) if "target" in n]
    tnames = [d.signal_names[i] for i in targets]
    r = d.w[:, targets] if targets else None
    keep = [i for i in range(d.w.shape[1]) if i not in targets]
    d = d.replace(w=d.w[:, keep], signal_names=tuple(d.signal_names[i] for i in keep))
    if heater is not None:
        names = _heater_names(d)
        if heater not in names:
            raise ConfigError(f"--heater {heater}: {what} has heaters {', '.join(names)}")
        i = names.index(heater)
        d = data_mod.keep_outputs(d, [d.output_names[i]], what)
        if d.n_inputs > 1:
            ins = [n for n in d.input_names if n.split("_pwm")[0] == heater]
            if ins:
                d = data_mod.keep_inputs(d, ins, what)
        if r is not None:
            mine = [j for j, n in enumerate(tnames) if n.startswith(heater + "_")]
            r = r[:, mine] if mine else None
    if d.n_inputs != d.n_outputs:
        raise ConfigError(f"{what}: {d.n_inputs} inputs and {d.n_outputs} outputs; a firmware "
                          "PID needs one heater per sensor (choose one with --heater)")
    return d, r


def _default_setpoint(r) -> float | None:
    if r is None:
        return None
    v = np.asarray(r, np.float64).ravel()
    v = v[v > 0]
    if not v.size:
        return None
    vals, counts = np.unique(np.round(v), return_counts=True)
    return float(vals[np.argmax(counts)])


def _fit_best(est, val, seed, say):
    from ..identify import fit
    from ..validate import compare

    best = None
    for fam in FAMILIES:
        try:
            res = fit(est, fam, seed=seed)
            score = float(compare(res.model, val)["mean_fit_percent"])
        except JThermoError as exc:
            say(f"fit {fam}: {exc}")
            continue
        say(f"fit {fam}: {score:.1f} % on validation")
        if math.isfinite(score) and (best is None or score > best[2]):
            best = (fam, res, score)
    if best is None:
        raise ControlError("calibrate: no model family could be fitted to the record")
    return best


def _judge(ctrls: dict, plant, env, r, duration, seed, rollouts) -> dict:
    kinds = ("tracking", "load", "preheat")
    scs = {k: model_scenario(k, plant, duration, jax.random.key(int(seed) + 7919),
                             n_rollouts=int(rollouts), envelope=env, setpoint=r) for k in kinds}
    out = {}
    for name, c in ctrls.items():
        m = {k: metrics(run_rollouts(plant, c, scs[k]), scs[k]) for k in kinds}
        out[name] = {"mse": float(m["tracking"]["mse"]),
                     "saturated_fraction": float(m["tracking"]["saturated_fraction"]),
                     "overshoot_C": float(m["preheat"]["overshoot_C"]),
                     "load_mse": float(m["load"]["mse"])}
    return out


def calibrate(est_path, out, *, validation=None, firmware: str = "klipper", heater=None,
              setpoint=None, seed: int = 0, steps: int = STEPS, rollouts: int = ROLLOUTS,
              progress: Callable[[str], None] | None = None) -> dict:
    """Records -> tuned firmware PID, its settings and a report in folder `out` (module
    docstring). Returns the JSON-ready report (`model`, `setpoints`, `finding`,
    `controllers`, `floor_plus_noise`, `firmware`, `files`)."""
    from .. import io

    say = progress or (lambda s: None)
    if firmware not in settings.FILE_NAMES:
        raise ConfigError(f"--firmware must be one of {', '.join(settings.FILE_NAMES)}")
    est_raw = data_mod.load(est_path)
    est, r_log = _prepare(est_raw, heater, "EST")
    if validation is not None:
        val, _ = _prepare(data_mod.load(validation), heater, "--validation")
        if val.n_inputs != est.n_inputs or not data_mod.same_ts(val.ts, est.ts):
            raise ConfigError("--validation: not the estimation record's heaters or sample time")
    else:
        est, val = data_mod.split(est, 1.0 - HOLD_BACK)
        say(f"no validation record: the last {HOLD_BACK:.0%} of EST held back")
    heaters = _heater_names(est)
    fam, res, score = _fit_best(est, val, seed, say)
    model = res.model
    env = res.envelope if getattr(res, "envelope", None) is not None else Envelope.from_model(model)
    r = setpoint if setpoint is not None else _default_setpoint(r_log)
    r = check_reachable(model, env, env.default_setpoint(model) if r is None else r)
    try:
        val_model = _fit_best(val, val, seed, lambda s: None)[1].model
        check_reachable(val_model, env, r)
        plant_name = "a model fitted to the validation record"
    except JThermoError:
        val_model, plant_name = model, "the design model (the validation record gave no plant)"
    say(f"model {fam} ({score:.1f} % on validation); set point {np.round(r, 1).tolist()} °C")

    cfg = klippy.config_for(est_path) or {}
    max_power = float(cfg.get("max_power", 1.0))
    smooth = float(cfg.get("smooth_time", 1.0))
    u_hold = equilibrium_input(model, r, env.signals(model))
    kw = {"ts": float(est.ts), "max_power": max_power, "smooth_time": smooth, "u_hold": u_hold}
    relay = tuning_start(design("pid_relay", model, setpoint=r), model, env, r)
    start = from_standard(relay.kp, relay.ti, relay.td, **kw)
    duration = model_duration(model)
    say(f"tuning the firmware PID ({steps} steps, {rollouts} rollouts)")
    tuned = tune_own_plant("pid_relay", model, envelope=env, setpoint=r, rollouts=rollouts,
                           steps=steps, seed=seed, start=start, duration=duration,
                           classical=("pi_lambda",))
    final = tuned["tuned"].rounded()

    ctrls = {"firmware_pid": final}
    kinds = {"firmware_pid": "firmware_pid"}
    dp = design_point(model, setpoint=r)
    try:
        cal = [pid_calibrate(dp, float(np.asarray(r)[i]), i, max_power=max_power)
               for i in range(est.n_outputs)]
        ctrls["pid_calibrate"] = KlipperPID([c.pid_kp for c in cal], [c.pid_ki for c in cal],
                                            [c.pid_kd for c in cal], **kw).rounded()
        kinds["pid_calibrate"] = "yardstick"
    except ControlError as exc:
        say(f"PID_CALIBRATE on the model: {exc}")
    if cfg.get("control") == "pid" and est.n_outputs == 1:
        ctrls["printer_config"] = KlipperPID(cfg["pid_kp"], cfg["pid_ki"], cfg["pid_kd"], **kw)
        kinds["printer_config"] = "yardstick"
    for f in ("pi_lambda", *MODEL_BASED):
        try:
            ctrls[f] = design(f, model, setpoint=r)
            kinds[f] = "yardstick" if f == "pi_lambda" else "model_based"
        except JThermoError:
            continue
    say(f"judging {len(ctrls)} controllers on {plant_name}")
    table = _judge(ctrls, val_model, env, r, duration, seed, rollouts)
    lim = limits(val_model, env, r, duration, seed)
    controllers = [{"name": n, "kind": kinds[n], **table[n]} for n in ctrls]

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    note = (f"jthermo calibrate: {fam} model, set point {np.round(r, 1).tolist()} C, "
            f"sample time {est.ts:g} s")
    fw_text = {"klipper": lambda: settings.klipper_cfg(final, heaters, note),
               "kalico": lambda: settings.kalico_cfg(final, heaters, None, note),
               "marlin": lambda: settings.marlin_gcode(final, heaters, note),
               "c": lambda: settings.c_source(final)}[firmware]()
    fw_path = out / settings.FILE_NAMES[firmware]
    from .._files import atomic_write_text

    atomic_write_text(fw_path, fw_text)
    ctrl_path = io.save(final, out / "controller.jtm",
                        meta={"family": "klipper_pid", "heaters": heaters, "model": fam})
    report = {"model": {"family": fam, "orders": dict(getattr(res, "orders", None) or {}),
                        "validation_fit_percent": score},
              "setpoints": np.asarray(r).tolist(), "heaters": heaters, "ts": float(est.ts),
              "finding": _finding(table, lim), "judged_on": plant_name,
              "controllers": controllers,
              "floor_plus_noise": lim["tracking_bound_mse"], "limits": lim,
              "gains": {n: ctrls[n].gains() for n in ctrls if isinstance(ctrls[n], KlipperPID)},
              "firmware": {firmware: str(fw_path)}, "controller_file": str(ctrl_path),
              "tuning": {"steps": int(steps), "rollouts": int(rollouts), "seed": int(seed),
                         "moved": tuned["moved"]}}
    md = out / "report.md"
    atomic_write_text(md, _markdown(report, fw_text))
    report["files"] = [str(fw_path), str(ctrl_path), str(md)]
    return report


def _finding(table: dict, lim: dict) -> str:
    fw = table["firmware_pid"]
    bound = lim.get("tracking_bound_mse")
    parts = [f"tuned firmware PID: set-point-change MSE {fw['mse']:.3g} °C²"]
    if bound:
        parts.append(f"{100 * (fw['mse'] / bound - 1):+.0f} % against the floor + noise {bound:.3g}")
    if fw["saturated_fraction"] > 0.25:
        parts.append(f"but it sits at an input limit {100 * fw['saturated_fraction']:.0f} % of the "
                     "set-point changes on the judging plant: not a settled loop, check before use")
    cal = table.get("pid_calibrate")
    if cal:
        if cal["saturated_fraction"] >= 0.25:
            parts.append(f"the PID_CALIBRATE yardstick failed (at a limit "
                         f"{100 * cal['saturated_fraction']:.0f} % of the time)")
        else:
            parts.append(f"{100 * (1 - fw['mse'] / cal['mse']):.0f} % below PID_CALIBRATE's gains")
    return "; ".join(parts)


def _markdown(rep: dict, fw_text: str) -> str:
    rows = ["| controller | kind | MSE °C² | at a limit | start-up overshoot °C | load MSE °C² |",
            "|---|---|---|---|---|---|"]
    rows += [f"| {c['name']} | {c['kind']} | {c['mse']:.4g} | {100 * c['saturated_fraction']:.0f} % "
             f"| {c['overshoot_C']:.2f} | {c['load_mse']:.4g} |" for c in rep["controllers"]]
    m = rep["model"]
    fence = "```"
    return "\n".join([
        "# Heater calibration", "",
        f"Model: {m['family']} {m['orders']}, {m['validation_fit_percent']:.1f} % simulation fit "
        f"on the validation record. Set point {rep['setpoints']} °C, sample time {rep['ts']:g} s.",
        "", f"Finding: {rep['finding']}.", "",
        f"Judged on {rep['judged_on']}; floor + noise (no controller within the input limits "
        f"does better on the set-point changes): {rep['floor_plus_noise']} °C².", "",
        *rows, "", "## Settings", "", fence, fw_text.rstrip(), fence, ""])


__all__ = ["FAMILIES", "HOLD_BACK", "MODEL_BASED", "calibrate"]
