"""End-to-end gradient tuning of controllers over vmapped closed-loop rollouts.

The mean closed-loop cost over B disturbance rollouts (and optionally over a plant ensemble)
is differentiated with `eqx.filter_value_and_grad` with respect to every inexact array leaf of
the controller, and minimised with optax Adam in one jitted `make_step`; the loop over
iterations and the progress report stay outside jit.

Parameters stay valid by construction: every leaf whose entries are all positive at the start
(gains, integral times, filter time constants, LQ weights) is optimised in log space,
$\\theta = e^{z}$, so it stays positive and Adam's steps are relative; other leaves (e.g. a
decoupling matrix with signs) are optimised as they are. Non-finite gradients are zeroed, and
the best finite iterate seen is returned, so tuning never hands back a NaN or diverging
controller.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .control._base import AbstractController
from .errors import ControlError

# ----------------------------------------------------------------------------------------
# generic minimiser over the controller's array leaves
# ----------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """Outcome of `tune`: the best controller found and the cost history."""

    controller: AbstractController
    history: np.ndarray          # training cost per iteration (before that iteration's update)
    start_cost: float            # training cost of the starting controller
    tuned_cost: float            # training cost of the returned controller
    seconds: float = 0.0         # wall time of the tuning loop, s


def _log_mask(params):
    """True for leaves optimised in log space (all entries positive at the start)."""
    return jax.tree_util.tree_map(lambda x: bool(np.all(np.asarray(x) > 0)), params)


def _to_z(params, mask):
    return jax.tree_util.tree_map(lambda x, m: jnp.log(x) if m else x, params, mask)


def _from_z(z, mask):
    return jax.tree_util.tree_map(lambda v, m: jnp.exp(v) if m else v, z, mask)


def _finite_tree(tree) -> bool:
    return all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(tree))


def minimise(loss: Callable[[Any, Any], jax.Array], controller, batches: Sequence[Any], *,
             steps: int = 100, lr: float = 0.05, progress: Callable[[int, float], None] | None
             = None, filter_spec=eqx.is_inexact_array) -> TuneResult:
    """Minimise `loss(controller, batch)` over the controller's array leaves with Adam.

    **Arguments:**
    - `loss`: scalar, differentiable; `batch` is any pytree (scenarios, plants) that it reads.
    - `batches`: training batches, cycled through (one per iteration); all of the same shapes
      so that `make_step` compiles once.
    - `steps`: iterations; `lr`: Adam learning rate (relative steps for log-space leaves).
    - `progress`: called as `progress(i, cost)` after each iteration (outside jit).

    **Returns:** `TuneResult` with the best finite iterate (by training cost).
    """
    if steps < 0:
        raise ControlError(f"tune: steps must be >= 0, got {steps}")
    if not batches:
        raise ControlError("tune: no training batch")
    t0 = time.perf_counter()
    params, static = eqx.partition(controller, filter_spec)
    mask = _log_mask(params)
    z = _to_z(params, mask)
    opt = optax.adam(lr)
    opt_state = opt.init(eqx.filter(z, eqx.is_inexact_array))

    def objective(z, batch):
        return loss(eqx.combine(_from_z(z, mask), static), batch)

    @eqx.filter_jit
    def make_step(z, opt_state, batch):
        val, grads = eqx.filter_value_and_grad(objective)(z, batch)
        grads = jax.tree_util.tree_map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grads)
        updates, opt_state = opt.update(grads, opt_state, z)
        return eqx.apply_updates(z, updates), opt_state, val

    @eqx.filter_jit
    def value(z, batch):
        return objective(z, batch)

    history = []
    best_z, best_val = z, np.inf
    start = float(value(z, batches[0]))
    if not np.isfinite(start):
        raise ControlError("tune: the starting controller gives a non-finite cost")
    for i in range(steps):
        batch = batches[i % len(batches)]
        z_new, opt_state, val = make_step(z, opt_state, batch)
        val = float(val)
        history.append(val)
        # `val` is the cost of `z` (before this update): keep the best finite iterate
        if np.isfinite(val) and val < best_val and len(batches) == 1:
            best_z, best_val = z, val
        if progress is not None:
            progress(i, val)
        if not _finite_tree(z_new):
            break
        z = z_new
    # the last iterate has not been evaluated yet; with several batches judge all on batch 0
    last = float(value(z, batches[0]))
    if len(batches) > 1:
        best_z, best_val = (z, last) if np.isfinite(last) else (_to_z(params, mask), start)
        if best_val > start:
            best_z, best_val = _to_z(params, mask), start
    elif np.isfinite(last) and last < best_val:
        best_z, best_val = z, last
    if not np.isfinite(best_val):
        best_z, best_val = _to_z(params, mask), start
    tuned = eqx.combine(_from_z(best_z, mask), static)
    return TuneResult(controller=tuned, history=np.asarray(history), start_cost=start,
                      tuned_cost=float(best_val), seconds=time.perf_counter() - t0)


# ----------------------------------------------------------------------------------------
# closed-loop tuning on the virtual printer or a fitted model
# ----------------------------------------------------------------------------------------

#: the thesis' three test scenarios, tuned for jointly and reported separately
SCENARIOS = ("tracking", "powder", "print")
#: default scenario length for tuning and evaluation, s
DURATION = 600.0
#: offset added to the seed for held-out evaluation disturbances
HELD_OUT = 10_000


def _kinds(kind) -> tuple[str, ...]:
    from .closedloop import KINDS

    kinds = (kind,) if isinstance(kind, str) else tuple(kind)
    bad = [k for k in kinds if k not in KINDS]
    if not kinds or bad:
        raise ControlError(f"tune: unknown scenario {bad[0] if bad else '(none)'!r} "
                           f"(known: {', '.join(KINDS)})")
    return kinds


def make_batches(plants, kind=SCENARIOS, *, rollouts: int = 8, duration: float = DURATION,
                 seed: int = 0, n_batches: int = 1):
    """Training batches: for each batch, a list of `(plant, kind, Scenario)` with `rollouts`
    disturbance realisations each, drawn from `seed` (keys folded with plant and kind)."""
    from .closedloop import make_scenario

    if not isinstance(rollouts, (int, np.integer)) or rollouts < 1:
        raise ControlError(f"tune: rollouts must be a positive integer, got {rollouts!r}")
    kinds = _kinds(kind)
    base = jax.random.key(int(seed))
    out = []
    for b in range(n_batches):
        batch = []
        for i, p in enumerate(plants):
            for j, k in enumerate(kinds):
                key = jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(base, b), i), j)
                batch.append((p, k, make_scenario(k, p, duration, key, n_rollouts=int(rollouts))))
        out.append(batch)
    return out


def batch_cost(controller, batch, weights=None):
    """Mean closed-loop cost (`closedloop.cost`) over every `(plant, kind, scenarios[, scale])`
    of a batch, each divided by its `scale` (default 1): the quantity `tune` minimises."""
    from .closedloop import cost, rollouts

    total = 0.0
    for item in batch:
        plant, _, sc = item[:3]
        scale = item[3] if len(item) > 3 else 1.0
        total = total + cost(rollouts(plant, controller, sc), sc, weights) / scale
    return total / len(batch)


def tune(controller: AbstractController, plant, *, kind=SCENARIOS, scenarios=None,
         rollouts: int = 8, steps: int = 100, lr: float = 0.05, weights=None, seed: int = 0,
         plants=None, duration: float = DURATION, n_batches: int = 1, normalise: bool = True,
         progress: Callable[[int, float], None] | None = None) -> TuneResult:
    """Tune a controller end to end on simulated closed-loop cost.

    Minimises the mean of `closedloop.cost` over `rollouts` disturbance realisations of each
    scenario in `kind` (default the thesis' three tests), on `plant` or, for robust tuning, on
    every plant of `plants` (an ensemble: e.g. printers with another powder, perturbed
    parameters, fitted models). Gradients by `jax.grad` through the scanned simulations.

    **Arguments:**
    - `controller`: the starting controller (a classical design).
    - `plant`: a `Printer` or a fitted model; ignored when `plants` is given.
    - `kind`: a scenario name or a sequence of them; `scenarios`: ready-made training batches
      (as `make_batches` returns) instead.
    - `rollouts`, `duration` (s), `n_batches`: size of the training set, drawn from `seed`.
    - `steps`, `lr`: Adam iterations and learning rate; `weights`: `closedloop.cost` weights.
    - `normalise`: divide each scenario's cost by the starting controller's cost on it, so that
      every scenario (and plant) counts by its relative improvement: a gain in one scenario
      cannot buy a loss in another cheaply. Costs in the result are then relative (start = 1).
    - `progress`: called as `progress(i, cost)` after each iteration.

    **Returns:** `TuneResult` (the best finite iterate on the training batches).
    """
    pl = [plant] if plants is None else list(plants)
    if not pl:
        raise ControlError("tune: empty plant ensemble")
    batches = scenarios if scenarios is not None else make_batches(
        pl, kind, rollouts=rollouts, duration=duration, seed=seed, n_batches=n_batches)
    if normalise:
        batches = [[(p, k, sc, jax.lax.stop_gradient(_simulate_cost(p, controller, sc, weights)[1]))
                    for p, k, sc, *_ in batch] for batch in batches]
    return minimise(lambda c, b: batch_cost(c, b, weights), controller, batches, steps=steps,
                    lr=lr, progress=progress)


@eqx.filter_jit
def _simulate_cost(plant, controller, scenarios, weights):
    from .closedloop import cost, rollouts

    traj = rollouts(plant, controller, scenarios)
    return traj, cost(traj, scenarios, weights)


def evaluate(controller: AbstractController, plant, kind=SCENARIOS, seeds=(HELD_OUT,), *,
             rollouts: int = 8, duration: float = DURATION, weights=None) -> dict:
    """Held-out evaluation: per scenario, the mean cost and metrics over `rollouts`
    realisations for each seed in `seeds` (use seeds never used in tuning).

    **Returns:** `{"cost": mean over scenarios, "scenarios": {kind: {"cost", "mse", ...}}}`.
    """
    from .closedloop import make_scenario, metrics

    out = {}
    for k in _kinds(kind):
        costs, mets = [], []
        for s in seeds:
            sc = make_scenario(k, plant, duration, jax.random.key(int(s)),
                               n_rollouts=int(rollouts))
            traj, J = _simulate_cost(plant, controller, sc, weights)
            costs.append(float(J))
            mets.append(metrics(traj, sc))
        m = {name: float(np.mean([d[name] for d in mets])) for name in mets[0]}
        out[k] = {"cost": float(np.mean(costs)), **m}
    return {"cost": float(np.mean([v["cost"] for v in out.values()])), "scenarios": out}


def printer_model(printer):
    """The printer linearised at the window centre as a `StateSpace` (the grey-box model with
    the printer's known parameters): Jacobians of the continuous dynamics at the steady state,
    zero-order hold at Ts, outputs the bed sensors, operating point the steady input and the
    window-centre readings. Input delay is left out (a design model, not a plant)."""
    from .models._base import StateSpace
    from .models.greybox import zoh

    x0 = printer.initial_state()
    u0 = printer.steady_input()
    A, Bp, bs, _ = printer.linear_system()
    Ts = printer.surroundings
    t_far = jnp.asarray(1e9, x0.z.dtype)

    def f(z, u):
        return A @ z + Bp @ printer._power(u) + bs * Ts + printer._nonlinear(z, t_far, Ts)

    Ac = jax.jacfwd(f, 0)(x0.z, u0)
    Bc = jax.jacfwd(f, 1)(x0.z, u0)
    Ad, Bd = zoh(Ac, Bc, printer.ts)
    n = printer.n_outputs
    C = jnp.eye(Ad.shape[0], dtype=Ad.dtype)[:n] if not printer.has_areas else None
    if C is None:
        raise ControlError("printer_model: printers with areas 1–3 are not supported here")
    return StateSpace(Ad, Bd, C, ts=printer.ts, u0=u0, y0=printer.output(x0))


def _plant_from(plant, *, zones: int, powder: str, plant_seed: int):
    from .closedloop import REALISTIC_EFFECTS
    from .models._base import AbstractModel
    from .printer import Printer, make_printer

    if isinstance(plant, str):
        if plant != "printer":
            raise ControlError(f"tune: unknown plant {plant!r} (use 'printer' or pass a plant)")
        return make_printer(zones, REALISTIC_EFFECTS, powder=powder, seed=plant_seed)
    if isinstance(plant, (Printer, AbstractModel)):
        return plant
    raise ControlError(f"tune: unsupported plant {type(plant).__name__}")


def tune_report(controller_family: str, *, plant="printer", model=None, rollouts: int = 8,
                steps: int = 200, seed: int = 0, lr: float = 0.05, zones: int = 4,
                powder: str = "PA12", duration: float = DURATION, plant_seed: int = 0,
                eval_rollouts: int | None = None, weights=None,
                progress: Callable[[int, float], None] | None = None) -> dict:
    """Tune one controller family against the virtual printer and report on held-out seeds.

    Starts from the classical design of `controller_family` (see `control.design`) on `model`
    (default: the printer linearised at the window centre, `printer_model`), tunes it on
    disturbance seeds drawn from `seed`, and evaluates start, tuned and the lambda-tuned
    diagonal PI on the held-out seed `seed + HELD_OUT` in the three scenarios.

    **Returns:** a JSON-ready dict with `controller`, `start_cost`, `tuned_cost`,
    `lambda_pi_cost`, `improvement_percent` (100·(1 − tuned/lambda_pi)), `scenarios`
    (per-scenario MSE and cost before/after, and of the lambda PI), `history`, `seconds`, and
    the tuned controller under the key `"tuned"` (not JSON: pop it before writing).
    """
    from .control.design import design
    from .models._base import AbstractModel

    t0 = time.perf_counter()
    pl = _plant_from(plant, zones=zones, powder=powder, plant_seed=plant_seed)
    if model is None:
        model = pl if isinstance(pl, AbstractModel) else printer_model(pl)
    start = design(controller_family, model)
    lam_pi = design("pi_lambda", model)
    res = tune(start, pl, rollouts=rollouts, steps=steps, lr=lr, seed=seed, duration=duration,
               weights=weights, progress=progress)
    seeds = (int(seed) + HELD_OUT,)
    er = eval_rollouts or rollouts
    ev = {name: evaluate(c, pl, SCENARIOS, seeds, rollouts=er, duration=duration,
                         weights=weights)
          for name, c in (("start", start), ("tuned", res.controller), ("lambda_pi", lam_pi))}
    scen = {k: {"mse_before": ev["start"]["scenarios"][k]["mse"],
                "mse_after": ev["tuned"]["scenarios"][k]["mse"],
                "mse_lambda_pi": ev["lambda_pi"]["scenarios"][k]["mse"],
                "cost_before": ev["start"]["scenarios"][k]["cost"],
                "cost_after": ev["tuned"]["scenarios"][k]["cost"],
                "cost_lambda_pi": ev["lambda_pi"]["scenarios"][k]["cost"]} for k in SCENARIOS}
    tuned, lam_c = ev["tuned"]["cost"], ev["lambda_pi"]["cost"]
    return {"controller": controller_family, "start_cost": ev["start"]["cost"],
            "tuned_cost": tuned, "lambda_pi_cost": lam_c,
            "improvement_percent": 100.0 * (1.0 - tuned / lam_c), "scenarios": scen,
            "train_start_cost": res.start_cost, "train_tuned_cost": res.tuned_cost,
            "history": [float(h) for h in res.history], "rollouts": int(rollouts),
            "steps": int(steps), "seed": int(seed), "held_out_seeds": list(seeds),
            "duration": float(duration), "zones": int(getattr(pl, "zones", 0) or 0),
            "powder": powder, "seconds": time.perf_counter() - t0, "tuned": res.controller}
