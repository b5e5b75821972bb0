"""`calibrate`: from a heater's record to the PID settings its firmware runs.

1. **Records.** The estimation record (e.g. a `jthermo import` segment); a logged set point
   (`w_*_target*`) is neither an input nor an output and is left out of the fit, but gives the
   default set point (the most common non-zero target). Without a validation record the last
   `HOLD_BACK` of the estimation record is held back.
2. **Model.** Each family of `FAMILIES` is fitted with the public fit API; the one with the
   best simulation fit on the validation record is the design model. The same family fitted to
   the validation record is the cross-record plant every controller is judged on.
3. **Diagnosis** (`diagnose.diagnose` with `DIAGNOSE_MECHANISMS`, the hot-end's candidate
   physics, to keep it cheap): its first finding's sentence is the report's `finding`.
4. **Two-state hot-end model** (one heater): `mpc.fit_two_state` on the estimation record,
   its simulation fit on the validation record; its constants go to Marlin's `M306` and
   Kalico's `control: mpc`, and its fan transfer sizes the load step: the part-cooling fan
   from off to full at the set point, a heat sink of $a_f (r - T_a)/h$ duty.
5. **Controllers.** The firmware PID (`pid.KlipperPID`: Klipper's law at the record's sample
   time, its derivative smoothing, integral clamp and `max_power`) is tuned on the design
   model by `tuning.tune_firmware_pid` from the relay test's $K_u$, $T_u$ (`PID_CALIBRATE`
   on the model); its gains are rounded as `printer.cfg` takes them before it is judged.
   Yardsticks, each under Klipper's law: the gains `PID_CALIBRATE` computes on the same model
   (`pid.pid_calibrate`) and the gains the printer ran with (from the import's summary); the
   model-based controllers (`MODEL_BASED`, designed on the design model) and the lambda PI.
   With a two-state model, the firmware's own MPC (`mpc_law.FirmwareMPC`: Kalico's law with
   the exported constants, kind `firmware_mpc`).
6. **Judgement** (`judging`) on the cross-record plant, on rollouts neither tuned nor
   selected on: the set-point changes' MSE, the time at an input limit, the start-up
   overshoot, the load step's MSE, and what no controller beats, the full-power floor plus
   the noise (`tune.own.limits`). The relay PID is the bar the tuned one must beat unless it
   sits at a limit `tuning.MAX_SATURATED` of the set-point changes or more (a failed
   yardstick: then the lambda PI is).

Two cores: the diagnosis (from the first fitted family on) and the cross-record plant's fit
(once the design family is known) run in threads beside the main thread's fits and tuning; a
yardstick's judgement is compiled for one run (`tuning.runs(once=True)`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .. import data as data_mod
from ..closedloop import model_duration
from ..control.design import design, design_point
from ..errors import ConfigError, ControlError, JThermoError
from ..models.envelope import Envelope, check_reachable, equilibrium_input
from ..tune.own import limits
from . import judging, klippy, mpc, settings, tuning
from . import report as report_mod
from .judging import ACCEPT_OVERSHOOT_C, ACCEPT_SATURATED, KU_AGREEMENT, TU_AGREEMENT
from .mpc_law import FirmwareMPC
from .pid import KlipperPID
from .stages import Laps, timed

#: the model families tried, cheapest first
FAMILIES = ("arx", "oe")
#: share of the estimation record held back for validation when there is no validation record
HOLD_BACK = 0.3
#: model-based controllers designed on the design model and judged beside the PID
MODEL_BASED = ("imc", "lqg")
#: tuning defaults of the command (`--steps`, `--rollouts`): the compass search's iterations
#: at most after the grid of starts (it stops earlier once converged), the rollouts per scenario
STEPS, ROLLOUTS = 20, 4
#: the diagnosis' candidates: what a heater with a lagging sensor at 200 °C leaves out
DIAGNOSE_MECHANISMS = ("heater_lag", "radiative_loss", "input_delay")
#: the fan signal's name in a record (`w_<name>`), matched by this part
FAN = "fan"


def _heater_names(d: data_mod.IOData) -> list[str]:
    """Heater names of the outputs: `extruder_C` (the converted logs' unit suffix) -> `extruder`."""
    return [n.removesuffix("_C") for n in d.output_names]


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


def _fit_best(est, val, seed, say, lap, first=None):
    """`(family, result, validation fit %)` of the family of `FAMILIES` that simulates `val`
    best; `first(result)` is called once, on the first family fitted."""
    from ..identify import fit
    from ..validate import compare

    best = None
    for fam in FAMILIES:
        try:
            res = fit(est, fam, seed=seed)
            score = float(compare(res.model, val)["mean_fit_percent"])
        except JThermoError as exc:
            say(f"fit {fam}: {exc}")
            lap(f"fit {fam}")
            continue
        say(f"fit {fam}: {score:.1f} % on validation")
        lap(f"fit {fam}")
        if first is not None:
            first(res)
            first = None
        if math.isfinite(score) and (best is None or score > best[2]):
            best = (fam, res, score)
    if best is None:
        raise ControlError("calibrate: no model family could be fitted to the record")
    return best


def _fit_one(d, fam, seed):
    from ..identify import fit

    return fit(d, fam, seed=seed)


def _fan(d: data_mod.IOData):
    """The record's fan signal (0..1), or None."""
    idx = [i for i, n in enumerate(d.signal_names) if FAN in n.lower()]
    return None if not idx else np.asarray(d.w[:, idx[0]], np.float64)


def _two_state(est, val, heater_power, say) -> dict | None:
    """`mpc.fit_two_state` on EST, its simulation fit on VAL (None where it does not apply)."""
    from ..validate import fit_percent

    if est.n_outputs != 1:
        return None
    try:
        res = mpc.fit_two_state(est.y[:, 0], est.u[:, 0], _fan(est), ts=float(est.ts),
                                heater_power=heater_power)
    except JThermoError as exc:
        say(f"two-state model: {exc}")
        return None
    yv = mpc.simulate(res["constants"], val.u[:, 0], _fan(val), ts=float(val.ts),
                      ambient=res["ambient_C"], y0=float(val.y[0, 0]))
    res["validation_fit_percent"] = float(np.ravel(fit_percent(val.y[:, :1], yv[:, None]))[0])
    res["yhat"] = yv
    say(f"two-state model: {res['validation_fit_percent']:.1f} % on validation")
    return res


def _load(two: dict | None, r, env) -> tuple:
    """The load step (duty per input, or None: `model_scenario`'s) and what it is."""
    if two and two["fan"] and two["rates"]["fan_rate"] > 0:
        rt = two["rates"]
        size = rt["fan_rate"] * (float(np.asarray(r).ravel()[0]) - two["ambient_C"]) / rt["heating_rate"]
        if size > 0:
            what = (f"the part-cooling fan from off to full, a heat sink of {size:.3g} duty "
                    "(from the two-state fit)")
            return np.full(1, size), what
    return None, ("an input-referred heat sink of a quarter of the recorded duty's spread "
                  "(no fan in the record: no fan step)")


class _Stopped(Exception):
    """The command stopped (an error in another stage): the diagnosis ends at its next stage."""


def _diagnosis(est, val, seed, say, stop=None) -> dict:
    """The diagnosis' first finding (sentence and mechanism) or why there is none; it ends at
    its next stage once `stop` (a `threading.Event`) is set."""
    from ..diagnose import diagnose

    def stage(i, n, info):
        if stop is not None and stop.is_set():
            raise _Stopped

    say(f"diagnosis ({', '.join(DIAGNOSE_MECHANISMS)})")
    try:
        res = diagnose(est, val, seed=seed, mechanisms=DIAGNOSE_MECHANISMS, progress=stage)
    except _Stopped:
        return {"finding": "not run: the command stopped", "mechanism": None, "verdict": None}
    except JThermoError as exc:
        return {"finding": f"no diagnosis: {exc}", "mechanism": None, "verdict": None}
    f = res["findings"]
    if not f:
        return {"finding": "the diagnosis finds no significant mismatch among "
                f"{', '.join(DIAGNOSE_MECHANISMS)} (baseline fit "
                f"{res['baseline']['mean_fit_percent']:.1f} %).", "mechanism": None,
                "verdict": res["verdict"]}
    return {"finding": f[0]["summary"], "mechanism": f[0]["mechanism"],
            "confidence": f[0]["confidence"], "verdict": res["verdict"]}


def calibrate(est_path, out, *, validation=None, firmware: str = "klipper", heater=None,
              setpoint=None, seed: int = 0, steps: int = STEPS, rollouts: int = ROLLOUTS,
              heater_power: float = mpc.HEATER_POWER_W, diagnosis: bool = True,
              figures: bool = True, oracle: bool = False, command: str = "jthermo calibrate",
              progress: Callable[[str], None] | None = None) -> dict:
    """Records -> tuned firmware PID, its settings and a report in folder `out` (module
    docstring). `heater_power`: W, the scale of the MPC constants; `diagnosis`, `figures`:
    run the diagnosis, draw the figures; `oracle`: also tune the firmware PID on the judging
    plant itself (`_oracle`, in `limits`); `command`: named in the report beside them. Returns
    the JSON-ready report (`model`, `setpoints`, `finding`, `verdict`, `controllers`,
    `floor_plus_noise`, `load`, `mpc`, `firmware`, `files`)."""
    say = progress or (lambda s: None)
    lap = Laps()
    if firmware not in settings.FILE_NAMES:
        raise ConfigError(f"--firmware must be one of {', '.join(settings.FILE_NAMES)}")
    if not (isinstance(heater_power, (int, float)) and math.isfinite(heater_power)
            and heater_power > 0):
        raise ConfigError(f"--heater-power must be a positive number of watts, got {heater_power}")
    est, r_log = _prepare(data_mod.load(est_path), heater, "EST")
    if validation is not None:
        val, _ = _prepare(data_mod.load(validation), heater, "--validation")
        if val.n_inputs != est.n_inputs or not data_mod.same_ts(val.ts, est.ts):
            raise ConfigError("--validation: not the estimation record's heaters or sample time")
    else:
        est, val = data_mod.split(est, 1.0 - HOLD_BACK)
        say(f"no validation record: the last {HOLD_BACK:.0%} of EST held back")
    heaters = _heater_names(est)
    lap("records")
    # beside the main thread (on the other core): the diagnosis once a fitted family reaches
    # the set point (it needs the records only; an unreachable set point is then an error that
    # nothing waits for: the design model decides), the judging plant's fit once the
    # design family is known (the tuning needs the design model only; the judgement waits for
    # the judging plant). An error stops them at their next stage (`stop`).
    stop = threading.Event()
    pool = ThreadPoolExecutor(2)
    started = []

    def start_diagnosis():
        if diagnosis and not started:
            started.append(pool.submit(timed, _diagnosis, est, val, seed, say, stop))

    def first(fitted):
        try:
            _setpoint(fitted, setpoint, r_log)
        except JThermoError:    # the design model decides; the diagnosis waits for it
            return
        start_diagnosis()

    try:
        fam, res, score = _fit_best(est, val, seed, say, lap, first)
        model, env = res.model, _envelope(res)
        r = _setpoint(res, setpoint, r_log)
        say(f"model {fam} ({score:.1f} % on validation); set point {np.round(r, 1).tolist()} °C")
        start_diagnosis()
        plant_fit = pool.submit(timed, _judging_plant, val, fam, seed, model, env, r)
        pending = started[0] if started else None
        return _calibrate_rest(est, val, est_path, out, res, fam, score, model, env, r,
                               heaters, firmware=firmware, seed=seed,
                               steps=steps, rollouts=rollouts, heater_power=heater_power,
                               figures=figures, oracle=oracle, command=command, say=say,
                               plant_fit=plant_fit, pending=pending, lap=lap)
    except BaseException:
        stop.set()
        raise
    finally:
        pool.shutdown(wait=True)


def _envelope(res) -> Envelope:
    """The fit's envelope (its record's input and output ranges), or the model's."""
    env = getattr(res, "envelope", None)
    return env if env is not None else Envelope.from_model(res.model)


def _setpoint(res, setpoint, r_log):
    """The set point on the fitted model: `setpoint`, else the log's most common target, else
    the envelope's default; `ControlError` where the model cannot reach it."""
    env = _envelope(res)
    r = setpoint if setpoint is not None else _default_setpoint(r_log)
    return check_reachable(res.model, env, env.default_setpoint(res.model) if r is None else r)


def _judging_plant(val, fam, seed, model, env, r) -> tuple:
    """`(plant, what it is)`: the design's family fitted to the validation record, or the
    design model itself where that record gives no plant that reaches the set point."""
    try:
        val_model = _fit_one(val, fam, seed).model
        check_reachable(val_model, env, r)
        return val_model, "a model fitted to the validation record"
    except JThermoError:
        return model, "the design model (the validation record gave no plant)"


def _calibrate_rest(est, val, est_path, out, res, fam, score, model, env, r, heaters, *,
                    firmware, seed, steps, rollouts, heater_power, figures, oracle, command,
                    say, plant_fit, pending, lap) -> dict:
    """`calibrate` after the design model's fit: the two-state model, the tuning, the
    judgement, the files (the judging plant's fit `plant_fit` and the diagnosis `pending` run in
    other threads: the first is collected before the judgement, the second before the
    report)."""
    from .. import io
    from .._files import atomic_write_text

    two = _two_state(est, val, float(heater_power), say)
    load, load_what = _load(two, r, env)
    lap("two-state fit")

    cfg = klippy.config_for(est_path) or {}
    max_power = float(cfg.get("max_power", 1.0))
    smooth = float(cfg.get("smooth_time", 1.0))
    u_hold = equilibrium_input(model, r, env.signals(model))
    kw = {"ts": float(est.ts), "max_power": max_power, "smooth_time": smooth, "u_hold": u_hold}
    dp = design_point(model, setpoint=r)
    cal, ku, tu = judging.ultimate(dp, model, r, est.n_outputs, max_power, say)
    lap("relay tests")
    duration = model_duration(model)
    n_grid = len(tuning.ALPHAS) * len(tuning.BETAS) * len(tuning.GAMMAS) * len(tuning.RHOS)
    say(f"tuning the firmware PID (a grid of {n_grid} starts, at most {steps} search "
        f"iterations, {rollouts} rollouts)")
    tuned = tuning.tune_firmware_pid(model, env, r, ku, tu, duration=duration, seed=seed,
                                     rollouts=rollouts, steps=steps, kw=kw, load=load, say=say)
    final = tuned["controller"]
    lap("tuning")

    ctrls = {"firmware_pid": final}
    kinds = {"firmware_pid": "firmware_pid"}
    if cal is not None:
        ctrls["pid_calibrate"] = KlipperPID([c.pid_kp for c in cal], [c.pid_ki for c in cal],
                                            [c.pid_kd for c in cal], **kw).rounded()
        kinds["pid_calibrate"] = "yardstick"
    if cfg.get("control") == "pid" and est.n_outputs == 1:
        ctrls["printer_config"] = KlipperPID(cfg["pid_kp"], cfg["pid_ki"], cfg["pid_kd"], **kw)
        kinds["printer_config"] = "yardstick"
    if two is not None:
        ctrls["firmware_mpc"] = FirmwareMPC.from_constants(
            two["constants"], ts=float(est.ts), max_power=max_power, u_hold=u_hold)
        kinds["firmware_mpc"] = "firmware_mpc"
    for f in ("pi_lambda", *MODEL_BASED):
        try:
            ctrls[f] = design(f, model, setpoint=r)
            kinds[f] = "yardstick" if f == "pi_lambda" else "model_based"
        except JThermoError:
            continue
    lap("yardstick designs")
    (val_model, plant_name), *took = plant_fit.result()
    lap("waiting for the judging plant")
    lap.add("fit of the validation record (its thread)", *took)
    agree = judging.agreement(ku, tu, val_model, model, r, max_power)
    if agree:
        say(agree)
    say(f"judging {len(ctrls)} controllers on {plant_name}")
    judge_scs = tuning.scenarios(val_model, env, r, duration, seed + 1, rollouts, load)
    table, first = judging.judge(ctrls, val_model, judge_scs)
    lap("judgement")
    lim = limits(val_model, env, r, duration, seed)
    lap("floor + noise")
    if oracle and val_model is not model:
        lim["pid_oracle"] = judging.oracle(val_model, env, r, kw, duration=duration, seed=seed,
                                           rollouts=rollouts, steps=steps, load=load,
                                           scs=judge_scs, bound=lim["tracking_bound_mse"],
                                           max_power=max_power, say=say)
        lap("oracle")
    keys = ("mse", "saturated_fraction", "overshoot_C", "load_mse")
    why_not = judging.why_not(agree, table["firmware_pid"])
    if why_not:
        say(f"not a tuning to use: {why_not}")
    controllers = [{"name": n, "kind": kinds[n], **{k: table[n][k] for k in keys}} for n in ctrls]

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    note = (f"jthermo calibrate: {fam} model, set point {np.round(r, 1).tolist()} C, "
            f"sample time {est.ts:g} s")
    if why_not:
        note = f"NOT A TUNING TO USE: {why_not}\n{note}"
    consts = {heaters[0]: two["constants"]} if two else None
    fw_text = {"klipper": lambda: settings.klipper_cfg(final, heaters, note),
               "kalico": lambda: settings.kalico_cfg(final, heaters, consts, note),
               "marlin": lambda: settings.marlin_gcode(final, heaters, note, consts),
               "c": lambda: settings.c_source(final, note=note)}[firmware]()
    fw_path = out / settings.FILE_NAMES[firmware]
    atomic_write_text(fw_path, fw_text)
    ctrl_path = io.save(final, out / "controller.jtm",
                        meta={"family": "klipper_pid", "heaters": heaters, "model": fam})
    figs = None
    if figures:
        from ..validate import compare

        cmp = compare(model, val)
        yhat, fits = {fam: cmp["yhat"]}, {fam: cmp["fit_percent"]}
        if two:
            yhat["two-state"] = two["yhat"][:, None]
            fits["two-state"] = [two["validation_fit_percent"]]
        figs = report_mod.figures(out, val=val, yhat=yhat, fits=fits,
                                  models={"design": model, "validation": val_model},
                                  runs=first, ts=float(env.ts), duration=duration)
    lap("files and figures")
    diag, *took = pending.result() if pending is not None else ({"finding": "not run",
                                                                 "mechanism": None}, 0.0, 0.0)
    lap("waiting for the diagnosis")
    lap.add("diagnosis (its thread)", *took)
    report = {"model": {"family": fam, "orders": dict(getattr(res, "orders", None) or {}),
                        "validation_fit_percent": score},
              "setpoints": np.asarray(r).tolist(), "heaters": heaters, "ts": float(est.ts),
              "finding": diag["finding"], "diagnosis": diag,
              "verdict": report_mod.verdict(table, lim), "judged_on": plant_name,
              "supported": why_not is None, "why_not": why_not,
              "controllers": controllers,
              "floor_plus_noise": lim["tracking_bound_mse"], "limits": lim,
              "load": {"what": load_what, "duty": None if load is None else float(load[0]),
                       "firmware_pid_load_mse": table["firmware_pid"]["load_mse"]},
              "mpc": None if two is None else {k: v for k, v in two.items() if k != "yhat"},
              "gains": {n: ctrls[n].gains() for n in ctrls if isinstance(ctrls[n], KlipperPID)},
              "firmware": {firmware: str(fw_path)}, "controller_file": str(ctrl_path),
              "figures": figs or {},
              "tuning": {"steps": int(steps), "rollouts": int(rollouts), "seed": int(seed),
                         "start": tuned["start"], "factors": tuned["factors"],
                         "iterations": tuned["iterations"], "converged": tuned["converged"],
                         "refined": tuned["refined"], "design_model": tuned["row"]},
              "timing": lap.report()}
    md = out / "report.md"
    atomic_write_text(md, report_mod.markdown(report, fw_text, figs, command))
    report["files"] = [str(fw_path), str(ctrl_path), str(md)]
    return report


__all__ = ["ACCEPT_OVERSHOOT_C", "ACCEPT_SATURATED", "DIAGNOSE_MECHANISMS", "FAMILIES",
           "HOLD_BACK", "KU_AGREEMENT", "MODEL_BASED", "TU_AGREEMENT", "calibrate"]
