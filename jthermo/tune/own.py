"""Tuning a user's own plant: a controller designed from a fitted model and tuned on the
model's own scenarios (`closedloop.model_scenario`: its recording's sample time, set-point
changes around the operating point, input-referred loads, noise) with a cost whose terms are
normalised by the starting controller's values (`OWN_WEIGHTS`, `terms.normalised_weights`),
judged on held-out seeds, on an optional validation plant (a model fitted to another record),
against every classical design from the same fit. The start-up step (heaters off to the set
point: power-limited) is reported on its own with its overshoot and its full-power floor. A
tuned loop that does not settle or sits at its input limits is a failure, never an
improvement."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..closedloop import metrics, model_duration, model_scenario
from ..closedloop import rollouts as run_rollouts
from ..control.design import design
from ..control.pi import DiagonalPI, with_setpoint_weight
from ..models.operating import operating_point
from ..control.relay import DiagonalPID
from ..errors import ConfigError, ControlError
from ..models._base import AbstractModel
from ..models.envelope import Envelope, check_reachable, equilibrium_input
from .report import CLASSICAL
from .terms import TERMS, batch_parts, normalised_weights
from .training import HELD_OUT, make_batches, tune

#: the set-point weight b a designed PI / PID starts tuning from (b = 1 is a stationary point
#: of b = sin^2(theta), so the weight would never move): on the Klipper hot-end, tuned from
#: 0.95 the 200 C start-up overshoot is 1.47 C, from 1 (moved by rounding only) 1.9 C
#: (`python experiments/own_plant_overshoot.py --tune --b0 1 0.95 --steps 60 --rollouts 4`,
#: experiments/results/own_plant_overshoot.md)
START_SETPOINT_WEIGHT = 0.95

#: the scenarios an own plant is tuned and judged on: set-point changes and loads around the
#: operating point, where the heaters' power is not the limit
OWN_SCENARIOS = ("tracking", "load")
#: the start-up step (heaters off to the set point), judged and reported on its own: at full
#: power until near the set point whatever the controller, so its MSE says little of the tuning
STARTUP = "preheat"
#: default cost weights of own-plant tuning, each relative to its term's value for the
#: starting controller (`normalised_weights`, `term_scales`)
OWN_WEIGHTS = {"tracking": 1.0, "uniformity": 0.0, "effort": 0.1, "window": 0.1,
               "overshoot": 1.0}
#: the overshoot term's scale is at least this share of the tracking term's
OVERSHOOT_FLOOR = 1e-3
#: a loop at an input limit longer than this share of a scenario has failed
MAX_SATURATED = 0.9
#: ... and longer than this share of the set-point changes or the load (`OWN_SCENARIOS`), sized
#: so that a loop ten times faster than the plant never needs a limit: a bang-bang loop there
MAX_SATURATED_CHANGES = 0.25
#: a PI / PID starts tuning with its measurement-noise gain bounded: the standard deviation of
#: the input noise it makes is at most this share of the inputs' headroom at the set point
NOISE_SHARE = 0.1
#: the PI / PID-type classical designs (a firmware user's alternatives)
PID_TYPE = ("pi_untuned", "pi_lambda", "pi_decoupled", "pid_relay")
#: the quantities reported per scenario and controller
REPORTED = ("mse", "overshoot_C", "settling_time_s", "time_to_ready_s", "saturated_fraction",
            "input_variation")


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
    window before the run ends) and is not at an input limit most of the time (`MAX_SATURATED`;
    `MAX_SATURATED_CHANGES` in `OWN_SCENARIOS`: a bang-bang loop); else one line saying what
    is wrong. `scenarios`: `{kind: metrics}`."""
    for kind, m in scenarios.items():
        values = [x for v in m.values() for x in (v.values() if isinstance(v, dict) else (v,))]
        if not all(np.isfinite(v) for v in values):
            return f"the {who} loop gives non-finite figures in `{kind}`"
        limit = MAX_SATURATED_CHANGES if kind in OWN_SCENARIOS else MAX_SATURATED
        if m["saturated_fraction"] > limit:
            return (f"the {who} loop sits at an input limit {100 * m['saturated_fraction']:.0f} % "
                    f"of the time in `{kind}` (at most {100 * limit:.0f} %)")
        if kind in ("tracking", "preheat") and m["settling_time_s"] >= duration - 1e-9:
            return (f"the {who} loop does not settle within ±window in `{kind}` "
                    f"({duration:g} s run, MSE {m['mse']:.3g} °C²)")
    return None


def noise_gain(controller) -> np.ndarray:
    """Per loop, the gain from measurement noise to the input at high frequency (power
    fraction per °C): $K_p$ for a PI, $K_p (1 + T_d / (T_f + T_s))$ for a PID (its filtered
    derivative on the measurement, $T_f = T_d / N$)."""
    kp = np.abs(np.asarray(controller.kp, np.float64))
    if isinstance(controller, DiagonalPID):
        td = np.asarray(controller.td, np.float64)
        return kp * (1.0 + td / (td / controller.n_filter + controller.ts))
    return kp


def detuned(controller, s):
    """A PI / PID with its crossover about `s` times lower (per loop, $0 < s \\le 1$):
    $K_p s$ and $T_i / s$ (on a lag-dominated plant the crossover scales with $K_p$, and
    Ziegler–Nichols' $T_i$ with the crossover's period); $T_d$ kept (the relay test's fast lag)
    with its filter at least one sample, $T_f = \\max(T_d/N, T_s)$ (one $N$ for all loops)."""
    s = jnp.asarray(s, controller.kp.dtype)
    if isinstance(controller, DiagonalPID):
        n = min(controller.n_filter, float(np.min(np.asarray(controller.td))) / controller.ts)
        return DiagonalPID(controller.kp * s, controller.ti / s, controller.td, controller.u0,
                           ts=controller.ts, n_filter=n, u_min=controller.u_min,
                           u_max=controller.u_max, b=None if controller.b_angle is None
                           else controller.b)
    return eqx.tree_at(lambda c: (c.kp, c.ti), controller, (controller.kp * s, controller.ti / s))


def tuning_start(controller, model: AbstractModel, envelope: Envelope, setpoint):
    """The PI / PID a tuning starts from: `controller` `detuned` by the largest $s \\le 1$ per
    loop (bisection) that makes the input noise from the recording's measurement noise,
    `noise_gain` × `noise_std` (std), at most `NOISE_SHARE` of the inputs' headroom at the set
    point's equilibrium (a design whose noise alone swings the input across its limits is a
    bang-bang loop: e.g. Ziegler–Nichols on a low-lag heater), its derivative filter at least
    one sample; the set-point weight `START_SETPOINT_WEIGHT` added as a tuned leaf. Other
    controllers come back unchanged."""
    if not isinstance(controller, (DiagonalPI, DiagonalPID)):
        return controller
    z = controller.zones
    u = equilibrium_input(model, setpoint, envelope.signals(model))[:z]
    room = NOISE_SHARE * np.minimum(u - np.asarray(envelope.u_min)[:z],
                                    np.asarray(envelope.u_max)[:z] - u)
    sigma = np.asarray(envelope.noise_std)[:z]

    def too_noisy(s):
        return noise_gain(detuned(controller, s)) * sigma > room

    s = np.ones(z)
    if np.any(too_noisy(s)):
        lo, hi = np.zeros(z), np.ones(z)
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            bad = too_noisy(mid)
            hi, lo = np.where(bad, mid, hi), np.where(bad, lo, mid)
        s = np.where(too_noisy(s), np.maximum(lo, 1e-6), 1.0)
    c = detuned(controller, s)
    if c.b_angle is None:          # tune the set-point weight too
        c = with_setpoint_weight(c, START_SETPOINT_WEIGHT)
    return c


def tracking_floor(plant, envelope: Envelope, setpoint, duration: float, seed: int = 0,
                   kind: str = STARTUP, step_c=None) -> float | None:
    """Full-power floor of a scenario's MSE (°C²) on `plant` (`kind`: `STARTUP`, default, or
    the set-point changes of `tracking`): after each set-point change from level $a$ to $b$,
    every input at its limit towards $b$ (`u_max` up, `u_min` down) from the equilibrium at
    $a$, $y_k = a + S_k (u_{lim} - u_a)$ with the step response $S$, the error counted only
    until each output first reaches $b$ and taken as zero afterwards.

    For the start-up (from rest) this is a lower bound for any controller within the input
    limits on a plant whose heaters only heat (non-negative step responses, as a heater's fit
    has); for a sequence of changes it is an estimate that assumes each change starts from
    steady state. A step that full power does not complete within the run counts in full.
    None for a non-square plant. No tuning brings the MSE much below it: an acceptance
    asking for less is out of reach of the heaters, not of the tuner. `step_c`: the
    set-point changes' size (°C, `model_scenario`'s; default its own)."""
    if int(plant.n_inputs) != int(plant.n_outputs):
        return None
    sc = model_scenario(kind, plant, duration, seed, envelope=envelope, setpoint=setpoint,
                        step_c=step_c)
    ref = np.asarray(sc.r, np.float64)
    T = ref.shape[0]
    S = np.asarray(plant.step_response(T), np.float64)             # (T, ny, nu)
    w = envelope.signals(plant)
    levels = [np.asarray(sc.y0, np.float64)]
    starts = [0]
    for k in range(T):
        if np.any(np.abs(ref[k] - levels[-1]) > 1e-9):
            levels.append(ref[k])
            starts.append(k)
    total = 0.0
    for i in range(1, len(levels)):
        a, b = levels[i - 1], levels[i]
        n = (starts[i + 1] if i + 1 < len(starts) else T) - starts[i]
        up = float(np.mean(b - a)) > 0
        u_lim = np.asarray(envelope.u_max if up else envelope.u_min, np.float64)
        e = a + S[:n] @ (u_lim - equilibrium_input(plant, a, w)) - b
        before = np.cumsum((e if up else -e) >= 0.0, axis=0) == 0   # not yet at b
        total += float(np.sum(np.where(before, e, 0.0) ** 2))
    return total / ref.size


def limits(plant, envelope: Envelope, setpoint, duration: float, seed: int = 0) -> dict:
    """What no controller within the input limits does better than, on `plant` (°C²):
    `startup_floor_mse` and `tracking_floor_mse` (`tracking_floor` of the start-up and the
    set-point changes), `noise_mse` = $\\overline{\\sigma^2}$ of the recording's measurement
    noise (in every measured MSE: white noise is independent of the true error), and
    `tracking_bound_mse`, their sum for the set-point changes (None where a floor is)."""
    fl = tracking_floor(plant, envelope, setpoint, duration, seed, "tracking")
    noise = float(np.mean(np.square(envelope.noise_std)))
    return {"startup_floor_mse": tracking_floor(plant, envelope, setpoint, duration, seed),
            "tracking_floor_mse": fl, "noise_mse": noise,
            "tracking_bound_mse": None if fl is None else fl + noise}


def term_scales(controller, plant, *, rollouts: int, duration: float, seed: int, kw,
                kinds: Sequence[str] = OWN_SCENARIOS) -> dict[str, float]:
    """Each cost term's value (`terms.TERMS`) for `controller` on `plant`, averaged over the
    training scenarios of `kinds` (seed `seed`); the overshoot's scale is at least
    `OVERSHOOT_FLOOR` times the tracking term's (both °C²), so that a start without overshoot
    does not make its weight unbounded."""
    batch = make_batches([plant], kinds, rollouts=rollouts, duration=duration, seed=seed,
                         scenario_kw=kw)[0]
    parts = np.mean(np.asarray(batch_parts(controller, batch)), axis=0)
    scales = {k: float(parts[i]) for i, k in enumerate(TERMS)}
    scales["overshoot"] = max(scales["overshoot"], OVERSHOOT_FLOOR * scales["tracking"])
    return scales


def _held_out(ctrls, plant, seed, rollouts, duration, weights, kw, tuned_on) -> dict:
    """Per controller and scenario (`OWN_SCENARIOS` and `STARTUP`): the metrics `REPORTED`,
    the raw cost terms under their weights' names (`terms`), and the normalised `cost`; the
    controller's `cost` is the mean over the scenarios `tuned_on`."""
    kinds = (*OWN_SCENARIOS, STARTUP)
    scs = {k: model_scenario(k, plant, duration, jax.random.key(int(seed)),
                             n_rollouts=int(rollouts), **kw) for k in kinds}
    out = {}
    for name, c in ctrls.items():
        parts = np.asarray(batch_parts(c, [(plant, k, scs[k]) for k in kinds]))
        row = {}
        for i, k in enumerate(kinds):
            m = metrics(run_rollouts(plant, c, scs[k]), scs[k])
            terms = {t: float(parts[i, j]) for j, t in enumerate(TERMS)}
            row[k] = {**{q: m[q] for q in REPORTED}, "terms": terms,
                      "cost": float(sum(weights[t] * v for t, v in terms.items()))}
        row["cost"] = float(np.mean([row[k]["cost"] for k in tuned_on]))
        out[name] = row
    return out


def _best(designs, table, key) -> str | None:
    return min(designs, key=key) if designs else None


def _tracking(table, name) -> float:
    return table[name]["tracking"]["mse"]


def _verdicts(table, duration) -> str | None:
    return judge({k: table["tuned"][k] for k in (*OWN_SCENARIOS, STARTUP)}, duration)


def _comparison(table, designs, duration) -> dict:
    """Best classical design by normalised cost and by tracking MSE (of all, and of the PI /
    PID type, `PID_TYPE`), the tuned controller's improvement on each (percent, positive:
    below the design), and the designs that sit at an input limit more than
    `MAX_SATURATED_CHANGES` of the set-point changes (`bang_bang`)."""
    best = _best(designs, table, lambda f: table[f]["cost"])
    best_t = _best(designs, table, lambda f: _tracking(table, f))
    best_p = _best([f for f in designs if f in PID_TYPE], table, lambda f: _tracking(table, f))
    tuned = table["tuned"]
    return {
        "best_pid_type_tracking": best_p,
        "tracking_improvement_vs_best_pid_type_percent":
            100.0 * (1.0 - _tracking(table, "tuned") / _tracking(table, best_p)) if best_p
            else None,
        "bang_bang": sorted(f for f in (*designs, "tuned")
                            if table[f]["tracking"]["saturated_fraction"] > MAX_SATURATED_CHANGES),
        "best_classical": best,
        "best_classical_cost": table[best]["cost"] if best else None,
        "improvement_vs_best_classical_percent":
            100.0 * (1.0 - tuned["cost"] / table[best]["cost"]) if best else None,
        "best_classical_tracking": best_t,
        "tracking_improvement_vs_best_classical_percent":
            100.0 * (1.0 - _tracking(table, "tuned") / _tracking(table, best_t)) if best_t
            else None,
        "startup_overshoot_C": tuned[STARTUP]["overshoot_C"],
        "verdict": _verdicts(table, duration) or "settled"}


def tune_own_plant(controller_family: str, model: AbstractModel, *, plant=None,
                   envelope: Envelope | None = None, setpoint=None, validation_plant=None,
                   rollouts: int = 8, steps: int = 150, seed: int = 0, lr: float = 0.05,
                   duration: float | None = None, weights=None,
                   kinds: Sequence[str] = OWN_SCENARIOS,
                   references: Sequence[str] = ("pi_lambda",),
                   classical: Sequence[str] = CLASSICAL,
                   progress: Callable[[int, float], None] | None = None,
                   start=None) -> dict:
    """Design `controller_family` from the fitted `model` at the set point's equilibrium, tune
    it on `plant` (default the model) over the own-plant scenarios (`OWN_SCENARIOS`, built from
    `envelope`, default `Envelope.from_model`), and judge it on held-out seeds, the start-up
    step (`STARTUP`) included.

    The cost is $J = \\sum_i (w_i / s_i)\\,\\text{term}_i$ over `terms.TERMS`, with $s_i$ each
    term's value for the starting design on the training scenarios (`term_scales`): at the
    start every term contributes its weight, so each weight moves the result.

    - `setpoint`: °C, scalar or per output (default: the plant's operating point,
      `models.operating.operating_point`); one
      the heaters cannot hold is a `ConfigError` saying what they can reach.
    - `validation_plant`: a second model (e.g. fitted to another record) on which the tuned
      and classical controllers are judged as well, never tuned on.
    - `weights`: `{term: weight}` over `OWN_WEIGHTS` (tracking, uniformity, effort = mean
      squared input change, window, overshoot), before normalisation.
    - `kinds`: the scenarios tuned on (default `OWN_SCENARIOS`; add `STARTUP` to tune on the
      start-up step as well); the scales and the held-out cost use the same.
    - `start`: the controller tuning starts from (default `design(controller_family, ...)` at
      the set point, through `tuning_start`: a PI / PID gets its noise gain bounded, a
      derivative filter of at least one sample and the set-point weight
      `START_SETPOINT_WEIGHT` as a tuned leaf).
    - `classical`: the families `best_classical` is taken over (by held-out cost;
      `best_classical_tracking` by the tracking scenario's MSE).

    **Returns:** a JSON-ready dict (`setpoints`, `ts`, `duration`, `weights`, `term_scales`,
    `scenarios` per controller and scenario — the metrics `REPORTED`, the raw cost `terms`
    under their weights' names, the normalised cost — `improvement_percent` against the lambda
    PI, `best_classical`, `improvement_vs_best_classical_percent`,
    `tracking_improvement_vs_best_classical_percent`, `startup_overshoot_C`,
    `startup_floor_mse`, `tracking_floor_mse`, `noise_mse`, `tracking_bound_mse` (`limits`),
    `best_pid_type_tracking`, `bang_bang`, `validation` with the
    same comparison on the validation plant) and
    the tuned controller under `"tuned"`. Raises `ControlError` when the tuned loop does not
    settle or sits at its input limits (`judge`), start-up included: such a result is never
    an improvement.
    """
    t0 = time.perf_counter()
    if not isinstance(model, AbstractModel):
        raise ConfigError(f"tune: the design model must be a fitted model, got {type(model).__name__}")
    plant = model if plant is None else plant
    _same_plant_shape(model, plant, "tune: the plant")
    if validation_plant is not None:
        _same_plant_shape(model, validation_plant, "tune: the validation plant")
    env = (Envelope.from_model(model) if envelope is None else envelope).check(model)
    # the plant's one operating point (`models.operating`), held by the design model too
    r = np.asarray(operating_point(plant, env, setpoint).setpoint)
    for other, what in ((model, "the design model"), (validation_plant, "the validation plant")):
        if other is not None and other is not plant:
            try:
                check_reachable(other, env, r)
            except ConfigError as exc:
                raise ConfigError(f"tune: on {what}, {exc}") from None
    duration = model_duration(model) if duration is None else float(duration)
    kw = {"envelope": env, "setpoint": r}
    if start is None:
        start = tuning_start(design(controller_family, model, setpoint=r), model, env, r)
    designs = classical_at(model, r, classical)
    refs = [designs.get(f) or design(f, model, setpoint=r)
            for f in references if f != controller_family]
    kinds = tuple(kinds)
    scales = term_scales(start, plant, rollouts=rollouts, duration=duration, seed=seed, kw=kw,
                         kinds=kinds)
    w = normalised_weights({**OWN_WEIGHTS, **dict(weights or {})}, scales)
    res = tune(start, plant, kind=kinds, rollouts=rollouts, steps=steps, lr=lr,
               seed=seed, duration=duration, weights=w, references=refs,
               scenario_kw=kw, progress=progress)
    seeds = (int(seed) + HELD_OUT,)
    ctrls = {"start": start, "tuned": res.controller, **designs}
    held = _held_out(ctrls, plant, seeds[0], rollouts, duration, w, kw, kinds)
    problem = _verdicts(held, duration)
    if problem is not None:
        raise ControlError(f"tune: {problem} at set point {np.round(r, 2).tolist()} °C; "
                           "not reported as tuned")
    lam = held.get("pi_lambda")
    out = {"controller": controller_family, "setpoints": r.tolist(), "ts": float(env.ts),
           "duration": duration, "scenario_kinds": list(kinds), "startup": STARTUP,
           "envelope": env.to_dict(), "weights": {**OWN_WEIGHTS, **dict(weights or {})},
           "term_scales": scales, "normalised_weights": w,
           "start_cost": held["start"]["cost"], "tuned_cost": held["tuned"]["cost"],
           "lambda_pi_cost": lam["cost"] if lam else None,
           "improvement_percent": 100.0 * (1.0 - held["tuned"]["cost"] / lam["cost"])
           if lam else None,
           **{k: v for k, v in _comparison(held, designs, duration).items() if k != "verdict"},
           "saturated_fraction": {k: held["tuned"][k]["saturated_fraction"]
                                  for k in (*OWN_SCENARIOS, STARTUP)},
           "scenarios": held, "validation": None,
           "train_start_cost": res.start_cost, "train_tuned_cost": res.tuned_cost,
           "guard": {k: v for k, v in (res.guard or {}).items() if k != "candidates"},
           "guard_candidates": (res.guard or {}).get("candidates"),
           "moved": not all(np.allclose(np.asarray(a), np.asarray(b)) for a, b in zip(
               jax.tree_util.tree_leaves(eqx.filter(start, eqx.is_inexact_array)),
               jax.tree_util.tree_leaves(eqx.filter(res.controller, eqx.is_inexact_array)))),
           **limits(plant, env, r, duration, seeds[0]),
           "history": [float(h) for h in res.history], "rollouts": int(rollouts),
           "steps": int(steps), "seed": int(seed), "held_out_seeds": list(seeds)}
    if validation_plant is not None:
        val = _held_out(ctrls, validation_plant, seeds[0], rollouts, duration, w, kw, kinds)
        out["validation"] = {"scenarios": val, **_comparison(val, designs, duration),
                             **limits(validation_plant, env, r, duration, seeds[0])}
    out["seconds"] = time.perf_counter() - t0
    out["tuned"] = res.controller
    return out


__all__ = ["MAX_SATURATED", "MAX_SATURATED_CHANGES", "NOISE_SHARE", "OVERSHOOT_FLOOR",
           "OWN_SCENARIOS", "OWN_WEIGHTS", "PID_TYPE", "STARTUP", "classical_at", "detuned", "judge",
           "limits", "noise_gain", "term_scales", "tracking_floor", "tune_own_plant",
           "tuning_start"]
