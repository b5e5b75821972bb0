"""Tuning Klipper's PID law on a fitted model for what a printer's user judges: the set-point
changes' MSE with a start-up that does not overshoot and a loop that is not bang-bang.

1. **Parameters.** The relay / Ziegler–Nichols design (`PID_CALIBRATE`'s $K_u$, $T_u$ per
   heater) scales a standard-form PID under Klipper's law (`pid.from_standard`):
   $K_p = \\alpha K_u$, $T_i = \\beta T_u$, $T_d = \\gamma T_u$ and the derivative smoothing
   `smooth_time` $\\tau = \\rho T_d$ (Klipper's `smooth_time`: a first-order filter of the
   measurement's derivative; $\\tau$ below the sample time is the raw difference), one
   $(\\alpha, \\beta, \\gamma, \\rho)$ for every heater. Ziegler–Nichols is
   $(0.6, 0.5, 0.125)$. The derivative smoothing matters as much as the gains: on a record
   whose noise moves the raw difference, an unsmoothed derivative swings the duty across its
   limits and the loop is bang-bang long before its gain is high enough to follow a change.
2. **Score** on the design model's held-out rollouts (`evaluate`): admissible when the
   start-up overshoot is at most `MAX_OVERSHOOT_C`, the loop sits at an input limit at most
   `MAX_SATURATED` of the set-point changes and of the load step, and everything is finite;
   among admissible loops the lowest `score`, the set-point changes' MSE plus `LOAD_WEIGHT`
   times the load step's. An inadmissible loop ranks after every admissible one, by how far
   it is outside.
3. **Search.** The grid `ALPHAS` × `BETAS` × `GAMMAS` × `RHOS`, then a compass search from its
   best point in the logarithms of the four factors: each iteration scores the `2 * 4`
   neighbours at a factor `STEP` (one batch), moves to the best when it ranks better and
   halves the step's logarithm otherwise, and stops when the step is below `MIN_STEP` (converged) or
   after `steps` iterations. Every batch holds `BATCH` controllers, so the grid, every
   iteration and the judgement of the Klipper PIDs run one compiled program. The search
   never makes the result worse than its start.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..closedloop import metrics, model_scenario
from ..closedloop import rollouts as run_rollouts
from ..runtime import one_shot, simulate_compile
from ..tune.own import STARTUP
from .pid import PID_PARAM_BASE, KlipperPID, from_standard

#: the grid of starts: $K_p = \\alpha K_u$, $T_i = \\beta T_u$, $T_d = \\gamma T_u$,
#: `smooth_time` $= \\rho T_d$
ALPHAS = (0.3, 0.6, 1.0, 1.6)
BETAS = (0.5, 1.2)
GAMMAS = (0.05, 0.125)
RHOS = (0.1, 0.4)
#: the compass search's first step and the step below which it has converged (factors)
STEP, MIN_STEP = 1.6, 1.04
#: controllers per simulated batch (the grid's size is a multiple)
BATCH = 8
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


def _runs_fn(plant, stacked, sc):
    """The rollouts of every controller of a stacked batch (leading axis) on one scenario."""
    return eqx.filter_vmap(lambda c: run_rollouts(plant, c, sc))(stacked)


@functools.cache
def _runs_program(once: bool):
    """`_runs_fn` compiled: for the tuning's batch, run for the grid and every search
    iteration, with `jthermo simulate`'s options (a shorter compile, no slower run); for a
    structure simulated once (`once`: a yardstick's judgement) with LLVM at -O0
    (`runtime.ONE_SHOT`: the shortest compile)."""
    return eqx.filter_jit(_runs_fn, compiler_options=one_shot() if once else simulate_compile())


def padded(ctrls: list, size: int = BATCH) -> list:
    """`ctrls` repeated at the end to a multiple of `size` (one compiled batch shape)."""
    n = len(ctrls)
    return ctrls + [ctrls[-1]] * ((-n) % size)


def merged(scs: dict):
    """The scenarios of `scs` as one batch of rollouts (their kinds' rollouts one after the
    other) and each kind's slice of it; None where their shapes differ. On a fitted model a
    scenario's kind is only a label (the loop starts from `y0` either way), so one compiled
    program runs them all instead of one per kind."""
    vals = list(scs.values())
    first = vals[0]
    same = lambda a, b: jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b) and all(
        x.shape == y.shape for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)))
    plain = [dataclasses.replace(s, kind=first.kind, cold_start=False) for s in vals]
    if not all(same(plain[0], s) and s.window == first.window and s.ts == first.ts
               and s.edges == first.edges for s in plain):
        return None
    one = jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs), *plain)
    b = int(first.r.shape[0])
    return one, {k: slice(i * b, (i + 1) * b) for i, k in enumerate(scs)}


def runs(ctrls, plant, scs: dict, size: int = BATCH, once: bool = False) -> dict:
    """`{kind: Trajectory}` of controllers of one structure (e.g. the grid) simulated in
    batches of `size` (the last padded; `BATCH`: the tuning's compiled shape): leading axis
    the controller, then the rollout. The scenarios run as one batch where they can
    (`merged`). `once`: a structure simulated once, compiled for a short compile rather than
    a fast run (`_runs_program`)."""
    from ..models._base import AbstractModel

    run = _runs_program(bool(once))
    full = padded(list(ctrls), size)
    both = merged(scs) if isinstance(plant, AbstractModel) else None
    out: dict = {}
    for i in range(0, len(full), size):
        stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *full[i:i + size])
        if both is None:
            for k, s in scs.items():
                out.setdefault(k, []).append(run(plant, stacked, s))
            continue
        traj = run(plant, stacked, both[0])
        for k, sl in both[1].items():
            out.setdefault(k, []).append(jax.tree_util.tree_map(lambda x, sl=sl: x[:, sl], traj))
    n = len(ctrls)
    return {k: jax.tree_util.tree_map(lambda *xs: jnp.concatenate(xs)[:n], *v)
            for k, v in out.items()}


def rows(trajs: dict, scs: dict, n: int) -> list[dict]:
    """`evaluate`'s figures of each of the `n` controllers of `runs`' trajectories."""
    out = []
    for i in range(n):
        m = {k: metrics(jax.tree_util.tree_map(lambda x, i=i: x[i], t), scs[k])
             for k, t in trajs.items()}
        out.append(_row(m))
    return out


def evaluate_many(ctrls, plant, scs: dict) -> list[dict]:
    """`evaluate` of controllers of one structure, simulated in batches."""
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


def controller(factors, ku, tu, **kw) -> KlipperPID:
    """The Klipper PID of factors $(\\alpha, \\beta, \\gamma, \\rho)$ (module docstring), gains
    and smoothing rounded as `printer.cfg` takes them; `ku` duty per °C and `tu` s per heater;
    `kw` the law's other settings (`ts`, `max_power`, `u_hold`)."""
    a, b, g, rho = (float(f) for f in factors)
    ku, tu = np.asarray(ku, np.float64), np.asarray(tu, np.float64)
    return from_standard(a * ku, b * tu, g * tu, smooth_time=rho * g * tu, **kw).rounded()


def grid(ku, tu, **kw) -> list[tuple[tuple, KlipperPID]]:
    """`[((alpha, beta, gamma, rho), KlipperPID)]` over the grid (module docstring)."""
    return [(f, controller(f, ku, tu, **kw))
            for f in itertools.product(ALPHAS, BETAS, GAMMAS, RHOS)]


def ultimate(cal) -> tuple[np.ndarray, np.ndarray]:
    """Per heater $K_u$ (duty per °C) and $T_u$ (s) from `PID_CALIBRATE`'s gains on the model
    (`pid.Autotune` rows): $K_u = K_p / (0.6 \\cdot 255)$, $T_u = 2 K_p / K_i$."""
    kp = np.array([c.pid_kp for c in cal], np.float64)
    ki = np.array([c.pid_ki for c in cal], np.float64)
    return kp / (0.6 * PID_PARAM_BASE), 2.0 * kp / ki


def compass(start, row, score_batch, steps: int, step: float = STEP,
            min_step: float = MIN_STEP) -> tuple:
    """Compass search (module docstring) from factors `start` with figures `row`:
    `score_batch(list of factors) -> list of rows`. Returns (factors, row, iterations, converged)."""
    x = np.log(np.asarray(start, np.float64))
    h = math.log(step)
    it = 0
    while it < steps and h >= math.log(min_step):
        it += 1
        cands = [x + sgn * h * e for e in np.eye(x.size) for sgn in (1.0, -1.0)]
        figs = score_batch([tuple(np.exp(c)) for c in cands])
        j = min(range(len(cands)), key=lambda i: rank(figs[i]))
        if rank(figs[j]) < rank(row):
            x, row = cands[j], figs[j]
        else:
            h *= 0.5
    return tuple(float(v) for v in np.exp(x)), row, it, h < math.log(min_step)


def tune_firmware_pid(model, env, r, ku, tu, *, duration: float, seed: int, rollouts: int,
                      steps: int, kw: dict, load=None, say=lambda s: None) -> dict:
    """The grid, then the compass search from its best point (module docstring). `kw`: the
    law's `ts`, `max_power`, `u_hold` (its `smooth_time` is tuned). Returns `controller`
    (rounded gains), `row` (its `evaluate` figures on the design model), `start` (the grid's
    best factors), `factors` (the result's), `iterations`, `converged`, `refined` (whether
    the search moved) and `grid` (every start's figures)."""
    kw = {k: v for k, v in kw.items() if k != "smooth_time"}
    scs = scenarios(model, env, r, duration, seed, rollouts, load)

    def score_batch(factors):
        return evaluate_many([controller(f, ku, tu, **kw) for f in factors], model, scs)

    starts = list(itertools.product(ALPHAS, BETAS, GAMMAS, RHOS))
    table = sorted(zip(starts, score_batch(starts)), key=lambda t: rank(t[1]))
    abc, row0 = table[0]
    say(f"best start alpha {abc[0]:g}, beta {abc[1]:g}, gamma {abc[2]:g}, rho {abc[3]:g}: "
        f"set-point MSE {row0['mse']:.3g} °C², start-up overshoot {row0['overshoot_C']:.2f} °C")
    factors, row, its, conv = compass(abc, row0, score_batch, int(steps))
    best = controller(factors, ku, tu, **kw)
    say(f"firmware PID: set-point MSE {row['mse']:.3g} °C², start-up overshoot "
        f"{row['overshoot_C']:.2f} °C ({its} search iterations, "
        f"{'converged' if conv else 'not converged'})")
    return {"controller": best, "row": row, "start": list(abc), "factors": list(factors),
            "iterations": its, "converged": bool(conv), "refined": factors != tuple(abc),
            "grid": [{"alpha": a[0], "beta": a[1], "gamma": a[2], "rho": a[3], **rw}
                     for a, rw in table]}


__all__ = ["ALPHAS", "BATCH", "BETAS", "GAMMAS", "KINDS", "LOAD_WEIGHT", "MAX_OVERSHOOT_C",
           "MAX_SATURATED", "MIN_STEP", "RHOS", "STEP", "compass", "controller", "evaluate",
           "evaluate_many", "grid", "merged", "padded", "rank", "rows", "runs", "scenarios", "score",
           "tune_firmware_pid", "ultimate", "violation"]
