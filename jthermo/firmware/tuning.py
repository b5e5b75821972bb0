"""Tuning Klipper's PID law on a fitted model for what a printer's user judges: the set-point
changes' MSE with a start-up that does not overshoot and a loop that is not bang-bang.

1. **Starts.** The relay / Ziegler–Nichols design (`PID_CALIBRATE`'s $K_u$, $T_u$ per heater)
   spans a grid of standard-form PIDs $K_p = \\alpha K_u$, $T_i = \\beta T_u$,
   $T_d = \\gamma T_u$ (`ALPHAS` × `BETAS` × `GAMMAS`, one $(\\alpha, \\beta, \\gamma)$ for
   every heater), each under Klipper's law (`pid.from_standard`). Ziegler–Nichols is the
   point $(0.6, 0.5, 0.125)$; the grid reaches from a quarter of its gain to it, with slower
   integrals and longer derivatives (a heater whose sensor lags its block needs them).
2. **Score** on the design model's held-out rollouts (`evaluate`): admissible when the
   start-up overshoot is at most `MAX_OVERSHOOT_C`, the loop sits at an input limit at most
   `MAX_SATURATED` of the set-point changes and of the load step, and everything is finite;
   among admissible loops the lowest `score`, the set-point changes' MSE plus `LOAD_WEIGHT`
   times the load step's. An inadmissible loop ranks after every admissible one, by how far
   it is outside.
3. **Refine.** The best start is tuned by `tune.tune_own_plant` on the set-point changes,
   the load and the start-up (its overshoot term), and kept only when it scores better on
   the same held-out rollouts: the refinement never makes the result worse.
"""

from __future__ import annotations

import itertools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..closedloop import metrics, model_scenario
from ..closedloop import rollouts as run_rollouts
from ..errors import ControlError
from ..tune.own import STARTUP, tune_own_plant
from .pid import PID_PARAM_BASE, KlipperPID, from_standard

#: the grid of starts: $K_p = \\alpha K_u$, $T_i = \\beta T_u$, $T_d = \\gamma T_u$
ALPHAS = (0.15, 0.25, 0.4, 0.6)
BETAS = (0.5, 1.0, 2.0)
GAMMAS = (0.125, 0.25, 0.4)
#: the start-up overshoot a tuned loop may have, °C (the acceptance asks for at most 1 °C)
MAX_OVERSHOOT_C = 0.8
#: a loop at an input limit longer than this share of the set-point changes is bang-bang
MAX_SATURATED = 0.25
#: the load step's MSE in the score, relative to the set-point changes'
LOAD_WEIGHT = 0.5
#: the scenarios judged: set-point changes, the load step and the start-up
KINDS = ("tracking", "load", STARTUP)
#: the rollouts' seed offset: held out from the tuning's training seeds
HELD_OUT = 104_729


def scenarios(plant, env, r, duration, seed, rollouts, load=None) -> dict:
    """`{kind: Scenario}` of `KINDS` on `plant` (`load`: the load step per input, power
    fraction; default `model_scenario`'s)."""
    key = jax.random.key(int(seed) + HELD_OUT)
    return {k: model_scenario(k, plant, duration, key, n_rollouts=int(rollouts), envelope=env,
                              setpoint=r, load=load if k == "load" else None) for k in KINDS}


@eqx.filter_jit
def _runs(plant, stacked, sc):
    """The rollouts of every controller of a stacked batch (leading axis) on one scenario."""
    return eqx.filter_vmap(lambda c: run_rollouts(plant, c, sc))(stacked)


def runs(ctrls, plant, scs: dict) -> dict:
    """`{kind: Trajectory}` of controllers of one structure (e.g. the grid) simulated as one
    batch: leading axis the controller, then the rollout."""
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *ctrls)
    return {k: _runs(plant, stacked, s) for k, s in scs.items()}


def rows(trajs: dict, scs: dict, n: int) -> list[dict]:
    """`evaluate`'s figures of each of the `n` controllers of `runs`' trajectories."""
    out = []
    for i in range(n):
        m = {k: metrics(jax.tree_util.tree_map(lambda x, i=i: x[i], t), scs[k])
             for k, t in trajs.items()}
        out.append(_row(m))
    return out


def evaluate_many(ctrls, plant, scs: dict) -> list[dict]:
    """`evaluate` of controllers of one structure, simulated as one batch."""
    return rows(runs(ctrls, plant, scs), scs, len(ctrls))


def evaluate(ctrl, plant, scs: dict) -> dict:
    """`mse` (set-point changes), `saturated_fraction` (theirs), `load_mse`,
    `load_saturated_fraction`, `overshoot_C` (start-up), `startup_mse`."""
    return evaluate_many([ctrl], plant, scs)[0]


def _row(m: dict) -> dict:
    return {"mse": float(m["tracking"]["mse"]),
            "saturated_fraction": float(m["tracking"]["saturated_fraction"]),
            "load_mse": float(m["load"]["mse"]),
            "load_saturated_fraction": float(m["load"]["saturated_fraction"]),
            "overshoot_C": float(m[STARTUP]["overshoot_C"]),
            "startup_mse": float(m[STARTUP]["mse"])}


def violation(row: dict) -> float:
    """How far a loop is outside the admissible set (0: inside; inf: non-finite figures)."""
    if not all(math.isfinite(v) for v in row.values()):
        return math.inf
    return (max(0.0, row["overshoot_C"] - MAX_OVERSHOOT_C)
            + max(0.0, row["saturated_fraction"] - MAX_SATURATED)
            + max(0.0, row["load_saturated_fraction"] - MAX_SATURATED))


def score(row: dict) -> float:
    """The set-point changes' MSE plus `LOAD_WEIGHT` times the load step's, °C²."""
    return row["mse"] + LOAD_WEIGHT * row["load_mse"]


def rank(row: dict) -> tuple:
    """Sort key: admissible loops first, by `score`; the others by `violation`."""
    v = violation(row)
    return (v > 0, v, score(row))


def grid(ku, tu, **kw) -> list[tuple[tuple, KlipperPID]]:
    """`[((alpha, beta, gamma), KlipperPID)]` over the grid (module docstring), gains rounded
    as `printer.cfg` takes them; `ku` duty per °C and `tu` s per heater."""
    ku, tu = np.asarray(ku, np.float64), np.asarray(tu, np.float64)
    out = []
    for a, b, g in itertools.product(ALPHAS, BETAS, GAMMAS):
        out.append(((a, b, g), from_standard(a * ku, b * tu, g * tu, **kw).rounded()))
    return out


def ultimate(cal) -> tuple[np.ndarray, np.ndarray]:
    """Per heater $K_u$ (duty per °C) and $T_u$ (s) from `PID_CALIBRATE`'s gains on the model
    (`pid.Autotune` rows): $K_u = K_p / (0.6 \\cdot 255)$, $T_u = 2 K_p / K_i$."""
    kp = np.array([c.pid_kp for c in cal], np.float64)
    ki = np.array([c.pid_ki for c in cal], np.float64)
    return kp / (0.6 * PID_PARAM_BASE), 2.0 * kp / ki


def tune_firmware_pid(model, env, r, ku, tu, *, duration: float, seed: int, rollouts: int,
                      steps: int, kw: dict, load=None, say=lambda s: None) -> dict:
    """The grid, the best start refined (module docstring). Returns `controller` (rounded
    gains), `row` (its `evaluate` figures on the design model), `start` ((alpha, beta, gamma)
    of the best start), `refined` (whether the refinement was kept) and `grid` (every start's
    figures)."""
    scs = scenarios(model, env, r, duration, seed, rollouts, load)
    starts = grid(ku, tu, **kw)
    figs = evaluate_many([c for _, c in starts], model, scs)
    rows = [(abc, c, f) for (abc, c), f in zip(starts, figs)]
    rows.sort(key=lambda t: rank(t[2]))
    abc, best, row = rows[0]
    say(f"best start alpha {abc[0]:g}, beta {abc[1]:g}, gamma {abc[2]:g}: set-point MSE "
        f"{row['mse']:.3g} °C², start-up overshoot {row['overshoot_C']:.2f} °C")
    refined = False
    if steps > 0:
        try:
            res = tune_own_plant("pid_relay", model, envelope=env, setpoint=r, rollouts=rollouts,
                                 steps=steps, seed=seed, start=best, duration=duration,
                                 kinds=KINDS, classical=("pi_lambda",))
            cand = res["tuned"].rounded()
            crow = evaluate(cand, model, scs)
            if rank(crow) < rank(row):
                best, row, refined = cand, crow, True
        except ControlError as exc:
            say(f"refinement left out: {exc}")
    say(f"firmware PID: set-point MSE {row['mse']:.3g} °C², start-up overshoot "
        f"{row['overshoot_C']:.2f} °C ({'refined' if refined else 'the grid start'})")
    return {"controller": best, "row": row, "start": list(abc), "refined": refined,
            "grid": [{"alpha": a[0], "beta": a[1], "gamma": a[2], **rw} for a, _, rw in rows]}


__all__ = ["ALPHAS", "BETAS", "GAMMAS", "KINDS", "LOAD_WEIGHT", "MAX_OVERSHOOT_C",
           "MAX_SATURATED", "evaluate", "evaluate_many", "grid", "rank", "rows", "runs",
           "scenarios", "score",
           "tune_firmware_pid", "ultimate", "violation"]
