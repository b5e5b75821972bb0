"""Tuning a user's own plant: a controller designed from a fitted model and tuned on the
model's own scenarios (`closedloop.model_scenario`: its recording's sample time, set points,
loads and noise), judged on held-out seeds, on an optional validation plant (a model fitted
to another record), against every classical design from the same fit; a tuned loop that
does not settle or sits at its input limits is a failure, never an improvement."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import numpy as np

from ..closedloop import model_duration, model_scenario, simulate
from ..control.design import design
from ..control.relay import DiagonalPID
from ..errors import ConfigError, ControlError
from ..models._base import AbstractModel
from ..models.envelope import Envelope, check_reachable
from .report import CLASSICAL, evaluate
from .training import HELD_OUT, tune

#: the scenarios an own plant is tuned and judged on
OWN_SCENARIOS = ("tracking", "load", "preheat")
#: a loop at an input limit longer than this share of a scenario has failed
MAX_SATURATED = 0.9
#: the quantities reported per scenario and controller
REPORTED = ("mse", "overshoot_C", "settling_time_s", "time_to_ready_s", "saturated_fraction",
            "effort", "cost")


def _same_plant_shape(model: AbstractModel, other: AbstractModel, what: str) -> None:
    if (int(other.n_inputs), int(other.n_outputs)) != (int(model.n_inputs), int(model.n_outputs)):
        raise ConfigError(f"{what}: {other.n_inputs} inputs / {other.n_outputs} outputs, the "
                          f"design model has {model.n_inputs} / {model.n_outputs}")
    if abs(float(other.ts) - float(model.ts)) > 1e-6 * float(model.ts):
        raise ConfigError(f"{what}: runs at Ts {float(other.ts):g} s, the design model at "
                          f"{float(model.ts):g} s")


def classical_at(model, setpoint, families: Sequence[str] = CLASSICAL) -> dict:
    """`{family: controller}` of the classical designs at the set point's equilibrium; a rule
    that does not apply to the model (`ControlError`) is left out."""
    out = {}
    for f in families:
        try:
            out[f] = design(f, model, setpoint=setpoint)
        except ControlError:
            continue
    return out


def judge(scenarios: dict, duration: float, who: str = "tuned") -> str | None:
    """None when every scenario's loop is finite, settles (tracking and start-up: inside the
    window before the run ends) and is not at an input limit most of the time; else one line
    saying what is wrong. `scenarios`: `{kind: metrics}`."""
    for kind, m in scenarios.items():
        if not all(np.isfinite(v) for v in m.values()):
            return f"the {who} loop gives non-finite figures in `{kind}`"
        if m["saturated_fraction"] > MAX_SATURATED:
            return (f"the {who} loop sits at an input limit {100 * m['saturated_fraction']:.0f} % "
                    f"of the time in `{kind}`")
        if kind in ("tracking", "preheat") and m["settling_time_s"] >= duration - 1e-9:
            return (f"the {who} loop does not settle within ±window in `{kind}` "
                    f"({duration:g} s run, MSE {m['mse']:.3g} °C²)")
    return None


def tracking_floor(plant, envelope: Envelope, setpoint, duration: float, seed: int = 0
                   ) -> float | None:
    """Lower bound of the tracking step's MSE (°C²) on `plant` for any controller within the
    input limits: every heater at full power from the start, the error counted only until
    each output first reaches its set point and taken as zero afterwards. Valid for a plant
    whose heaters only heat (non-negative step responses, as a heater's fit has); a step that
    full power does not complete within the run counts in full. None for a non-square plant.
    No tuning can bring the tracking MSE below this: an acceptance asking for less is out of
    reach of the heaters, not of the tuner."""
    if int(plant.n_inputs) != int(plant.n_outputs):
        return None
    sc = model_scenario("tracking", plant, duration, seed, envelope=envelope, setpoint=setpoint)
    n = int(plant.n_outputs)
    full = DiagonalPID(np.zeros(n), np.full(n, 1e12), np.zeros(n),
                       np.asarray(envelope.u_max, np.float64)[:n], ts=float(plant.ts))
    tr = simulate(plant, full, sc)
    e = np.asarray(tr.y) - np.asarray(tr.r)
    before = np.cumsum(e >= 0.0, axis=0) == 0         # not yet at the set point
    return float(np.sum(np.where(before, e, 0.0) ** 2) / e.size)


def _evaluate_all(ctrls, plant, seeds, rollouts, duration, weights, kw) -> dict:
    out = {}
    for name, c in ctrls.items():
        ev = evaluate(c, plant, OWN_SCENARIOS, seeds, rollouts=rollouts, duration=duration,
                      weights=weights, scenario_kw=kw)
        out[name] = {k: {q: v[q] for q in REPORTED} for k, v in ev["scenarios"].items()}
        out[name]["cost"] = ev["cost"]
    return out


def tune_own_plant(controller_family: str, model: AbstractModel, *, plant=None,
                   envelope: Envelope | None = None, setpoint=None, validation_plant=None,
                   rollouts: int = 8, steps: int = 150, seed: int = 0, lr: float = 0.05,
                   duration: float | None = None, weights=None,
                   references: Sequence[str] = ("pi_lambda",),
                   classical: Sequence[str] = CLASSICAL,
                   progress: Callable[[int, float], None] | None = None) -> dict:
    """Design `controller_family` from the fitted `model` at the set point's equilibrium, tune
    it on `plant` (default the model) over the own-plant scenarios (`OWN_SCENARIOS`, built from
    `envelope`, default `Envelope.from_model`), and judge it on held-out seeds.

    **Arguments:**
    - `setpoint`: °C, scalar or per output (default `envelope.default_setpoint(model)`); one
      the heaters cannot hold is a `ConfigError` saying what they can reach.
    - `validation_plant`: a second model (e.g. fitted to another record) on which the tuned
      and classical controllers are judged as well, never tuned on.
    - `classical`: the families `best_classical` is taken over (by held-out cost).

    **Returns:** a JSON-ready dict (`setpoints`, `ts`, `duration`, `scenarios` per controller
    and scenario — mse, overshoot, settling, saturated fraction — `improvement_percent` against
    the lambda PI, `best_classical`, `improvement_vs_best_classical_percent`, `validation`)
    and the tuned controller under `"tuned"`. Raises `ControlError` when the tuned loop does
    not settle or sits at its input limits (`judge`): such a result is never an improvement.
    """
    t0 = time.perf_counter()
    if not isinstance(model, AbstractModel):
        raise ConfigError(f"tune: the design model must be a fitted model, got {type(model).__name__}")
    plant = model if plant is None else plant
    _same_plant_shape(model, plant, "tune: the plant")
    if validation_plant is not None:
        _same_plant_shape(model, validation_plant, "tune: the validation plant")
    env = (Envelope.from_model(model) if envelope is None else envelope).check(model)
    r = check_reachable(model, env, env.default_setpoint(model) if setpoint is None else setpoint)
    for other, what in ((plant, "the plant"), (validation_plant, "the validation plant")):
        if other is not None and other is not model:
            try:
                check_reachable(other, env, r)
            except ConfigError as exc:
                raise ConfigError(f"tune: on {what}, {exc}") from None
    duration = model_duration(model) if duration is None else float(duration)
    kw = {"envelope": env, "setpoint": r}
    start = design(controller_family, model, setpoint=r)
    designs = classical_at(model, r, classical)
    lam = designs.get("pi_lambda") or design("pi_lambda", model, setpoint=r)
    refs = [designs.get(f) or design(f, model, setpoint=r)
            for f in references if f != controller_family]
    res = tune(start, plant, kind=OWN_SCENARIOS, rollouts=rollouts, steps=steps, lr=lr,
               seed=seed, duration=duration, weights=weights, references=refs,
               scenario_kw=kw, progress=progress)
    seeds = (int(seed) + HELD_OUT,)
    ctrls = {"start": start, "tuned": res.controller, **designs}
    held = _evaluate_all(ctrls, plant, seeds, rollouts, duration, weights, kw)
    problem = judge({k: held["tuned"][k] for k in OWN_SCENARIOS}, duration)
    if problem is not None:
        raise ControlError(f"tune: {problem} at set point {np.round(r, 2).tolist()} °C; "
                           "not reported as tuned")
    best = min(designs, key=lambda f: held[f]["cost"]) if designs else None
    out = {"controller": controller_family, "setpoints": r.tolist(), "ts": float(env.ts),
           "duration": duration, "scenario_kinds": list(OWN_SCENARIOS),
           "envelope": env.to_dict(), "start_cost": held["start"]["cost"],
           "tuned_cost": held["tuned"]["cost"], "lambda_pi_cost": held["pi_lambda"]["cost"]
           if "pi_lambda" in held else None,
           "improvement_percent": 100.0 * (1.0 - held["tuned"]["cost"] / held["pi_lambda"]["cost"])
           if "pi_lambda" in held else None,
           "best_classical": best,
           "best_classical_cost": held[best]["cost"] if best else None,
           "improvement_vs_best_classical_percent":
               100.0 * (1.0 - held["tuned"]["cost"] / held[best]["cost"]) if best else None,
           "saturated_fraction": {k: held["tuned"][k]["saturated_fraction"] for k in OWN_SCENARIOS},
           "scenarios": held, "validation": None,
           "train_start_cost": res.start_cost, "train_tuned_cost": res.tuned_cost,
           "guard": {k: v for k, v in (res.guard or {}).items() if k != "candidates"},
           "guard_candidates": (res.guard or {}).get("candidates"),
           "moved": not all(np.allclose(np.asarray(a), np.asarray(b)) for a, b in zip(
               jax.tree_util.tree_leaves(eqx.filter(start, eqx.is_inexact_array)),
               jax.tree_util.tree_leaves(eqx.filter(res.controller, eqx.is_inexact_array)))),
           "tracking_floor_mse": tracking_floor(plant, env, r, duration, seeds[0]),
           "history": [float(h) for h in res.history], "rollouts": int(rollouts),
           "steps": int(steps), "seed": int(seed), "held_out_seeds": list(seeds)}
    if validation_plant is not None:
        val = _evaluate_all(ctrls, validation_plant, seeds, rollouts, duration, weights, kw)
        vbest = min(designs, key=lambda f: val[f]["cost"]) if designs else None
        out["validation"] = {
            "scenarios": val, "verdict": judge({k: val["tuned"][k] for k in OWN_SCENARIOS},
                                               duration) or "settled",
            "best_classical": vbest,
            "improvement_vs_best_classical_percent":
                100.0 * (1.0 - val["tuned"]["cost"] / val[vbest]["cost"]) if vbest else None,
            "tracking_floor_mse": tracking_floor(validation_plant, env, r, duration, seeds[0])}
    out["seconds"] = time.perf_counter() - t0
    out["tuned"] = res.controller
    return out


__all__ = ["MAX_SATURATED", "OWN_SCENARIOS", "classical_at", "judge", "tracking_floor",
           "tune_own_plant"]
