"""The generic minimiser of `tune`: Adam over a controller's array leaves, positive leaves in
log space, non-finite gradients zeroed, the best finite iterate (and snapshots for a
validation guard) kept."""

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

from ..control._base import AbstractController
from ..errors import ControlError


@dataclasses.dataclass(frozen=True)
class TuneResult:
    """Outcome of `tune`: the controller returned, the cost history and the guard's verdict."""

    controller: AbstractController
    history: np.ndarray          # training cost per iteration (before that iteration's update)
    start_cost: float            # training cost of the starting controller
    tuned_cost: float            # training cost of the returned controller
    seconds: float = 0.0         # wall time of the tuning loop, s
    snapshots: tuple = ()        # (iteration, training cost, controller) kept for the guard
    guard: dict | None = None    # validation check of `tune` (None: not run)


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
             = None, filter_spec=eqx.is_inexact_array, snapshots: int = 0) -> TuneResult:
    """Minimise `loss(controller, batch)` over the controller's array leaves with Adam.

    **Arguments:**
    - `loss`: scalar, differentiable; `batch` is any pytree (scenarios, plants) that it reads.
    - `batches`: training batches, cycled through (one per iteration); all of the same shapes
      so that `make_step` compiles once.
    - `steps`: iterations; `lr`: Adam learning rate (relative steps for log-space leaves).
    - `progress`: called as `progress(i, cost)` after each iteration (outside jit).
    - `snapshots`: keep about this many finite iterates along the way (plus the start, the
      best and the last) in `TuneResult.snapshots`, for a validation guard.

    **Returns:** `TuneResult` with the best finite iterate (by training cost).
    """
    if not isinstance(steps, (int, np.integer)) or steps < 0:
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
    every = max(1, steps // snapshots) if snapshots else 0
    kept = [(0, start, z)] if snapshots else []
    for i in range(steps):
        batch = batches[i % len(batches)]
        z_new, opt_state, val = make_step(z, opt_state, batch)
        val = float(val)
        history.append(val)
        # `val` is the cost of `z` (before this update): keep the best finite iterate
        if np.isfinite(val) and val < best_val and len(batches) == 1:
            best_z, best_val = z, val
        if every and i > 0 and i % every == 0 and np.isfinite(val):
            kept.append((i, val, z))
        if progress is not None:
            progress(i, val)
        if not _finite_tree(z_new):
            break
        z = z_new
    # the last iterate has not been evaluated yet; with several batches judge all on batch 0
    last = float(value(z, batches[0]))
    if snapshots and np.isfinite(last):
        kept.append((len(history), last, z))
    if len(batches) > 1:
        best_z, best_val = (z, last) if np.isfinite(last) else (_to_z(params, mask), start)
        if best_val > start:
            best_z, best_val = _to_z(params, mask), start
    elif np.isfinite(last) and last < best_val:
        best_z, best_val = z, last
    if not np.isfinite(best_val):
        best_z, best_val = _to_z(params, mask), start
    if snapshots and all(zz is not best_z for _, _, zz in kept):
        kept.append((-1, best_val, best_z))
    tuned = eqx.combine(_from_z(best_z, mask), static)
    snaps = tuple((i, v, eqx.combine(_from_z(zz, mask), static)) for i, v, zz in kept)
    return TuneResult(controller=tuned, history=np.asarray(history), start_cost=start,
                      tuned_cost=float(best_val), seconds=time.perf_counter() - t0,
                      snapshots=snaps)

