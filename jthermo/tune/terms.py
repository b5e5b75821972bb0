"""The lean closed loop of tuning: cost terms and the measured-output MSE accumulated in the
scan carry (`simulate_terms`, `rollout_terms`), and batches of `(plant, kind, scenarios)`
grouped into one vmapped simulation per kind and plant structure (`group_batch`,
`batch_terms`)."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..closedloop import DEFAULT_WEIGHTS, initial_state
from ..control._base import AbstractController
from ..errors import ControlError
from ..models._base import AbstractModel
from ..printer import Printer


def _weights(weights) -> dict[str, float]:
    w = dict(DEFAULT_WEIGHTS)
    if weights is not None:
        bad = [k for k in weights if k not in DEFAULT_WEIGHTS]
        if bad:
            raise ControlError(f"tune: unknown cost weight `{bad[0]}` "
                               f"(known: {', '.join(DEFAULT_WEIGHTS)})")
        w.update(weights)
    return w


def _plant_functions(plant):
    """`(step(x, u, d), measure(x, d) -> (y_clean, temperatures))` from public plant APIs,
    with everything that does not change over time built once, outside the scan."""
    if isinstance(plant, Printer):
        disc = plant.discretise()
        return disc.step, lambda x, d: (disc.output(x), disc.temperatures(x))
    if isinstance(plant, AbstractModel):
        m = plant
        if type(plant).step is AbstractModel.step and type(plant).output is AbstractModel.output:
            m = plant.to_statespace()

        def step(x, u, d):
            return m.step(x, u, d.w if d.w.shape[-1] else None)

        def measure(x, d):
            y = m.output(x) + d.dy
            return y, y

        return step, measure
    raise ControlError(f"tune: unsupported plant {type(plant).__name__} "
                       "(a Printer or a fitted model)")


def simulate_terms(plant, controller: AbstractController, scenario, weights=None, *,
                   smoothing: float = 0.1) -> Float[Array, 2]:
    """One closed-loop run reduced to `[cost, mse]` inside the scan (nothing of size T kept).

    `cost` equals `closedloop.cost(simulate(...), scenario, weights)` and `mse` equals
    `closedloop.metrics(...)["mse"]` (measured outputs against the set point), both
    differentiable in the controller. `scenario` is one (unbatched) `closedloop.Scenario`.
    """
    w = _weights(weights)
    step, measure = _plant_functions(plant)
    x0 = initial_state(plant, scenario)
    d0 = jax.tree.map(lambda a: a[0], scenario.d)
    c0 = controller.init(measure(x0, d0)[0] + scenario.v[0], scenario.r[0])
    edges = np.asarray(scenario.edges, int).reshape(-1, 2)
    dt = scenario.r.dtype
    eps = 0.1 * smoothing
    T = scenario.r.shape[0]

    def body(carry, inp):
        x, c, u_prev, acc = carry
        k, r, d, v, s = inp
        y_clean, temps = measure(x, d)
        y = y_clean + v
        u, c = controller.step_schedule(c, y, r, s)
        u = jnp.clip(u, 0.0, 1.0)
        e = temps - r
        unif = jnp.mean((temps[edges[:, 0]] - temps[edges[:, 1]]) ** 2) if edges.size \
            else jnp.zeros((), dt)
        du = jnp.where(k == 0, 0.0, jnp.mean((u - u_prev) ** 2))
        win = jnp.mean(jax.nn.sigmoid((jnp.sqrt(e ** 2 + eps ** 2) - scenario.window) / smoothing))
        acc = acc + jnp.stack([jnp.mean(e ** 2), unif, du, win, jnp.mean((y - r) ** 2)])
        return (step(x, u, d), c, u, acc), None

    u_shape = jax.eval_shape(lambda: controller.step(c0, scenario.r[0], scenario.r[0])[0])
    init = (x0, c0, jnp.zeros(u_shape.shape, dt), jnp.zeros((5,), dt))
    (_, _, _, acc), _ = jax.lax.scan(
        body, init, (jnp.arange(T), scenario.r, scenario.d, scenario.v, scenario.s))
    J = (w["tracking"] * acc[0] + w["window"] * acc[3]) / T + w["effort"] * acc[2] / max(T - 1, 1)
    if edges.size:
        J = J + w["uniformity"] * acc[1] / T
    return jnp.stack([J, acc[4] / T])


def rollout_terms(plant, controller: AbstractController, scenarios, weights=None, *,
                  smoothing: float = 0.1) -> Float[Array, "B 2"]:
    """`simulate_terms` for each rollout of a batched `Scenario` (vmap): `(B, 2)` = cost, mse."""
    if scenarios.r.ndim != 3:
        raise ControlError("tune: scenarios need a leading rollout axis")
    return jax.vmap(lambda sc: simulate_terms(plant, controller, sc, weights,
                                              smoothing=smoothing))(scenarios)


class _Group(eqx.Module):
    """Items of a batch that share a scenario kind and a plant structure, stacked: the plants
    (leading axis P, or one plant with `stacked=False`) and their scenarios `(P, B, ...)`."""

    plants: Any
    scenarios: Any
    index: tuple = eqx.field(static=True)      # positions of these items in the batch
    stacked: bool = eqx.field(static=True)


def _same_structure(a, b) -> bool:
    la, sa = eqx.partition(a, eqx.is_array)
    lb, sb = eqx.partition(b, eqx.is_array)
    if jax.tree.structure(la) != jax.tree.structure(lb):
        return False
    if any(x.shape != y.shape or x.dtype != y.dtype for x, y in
           zip(jax.tree.leaves(la), jax.tree.leaves(lb))):
        return False
    return bool(eqx.tree_equal(sa, sb))


def group_batch(batch) -> tuple[_Group, ...]:
    """Stack the items `(plant, kind, scenarios)` of a batch that can share one vmapped
    simulation (same kind and same plant structure, e.g. a `plant_ensemble`): one trace and
    one compilation per group instead of per item."""
    groups: list[list[int]] = []
    for i, it in enumerate(batch):
        for g in groups:
            j = g[0]
            if batch[j][1] == it[1] and _same_structure(batch[j][0], it[0]) and \
                    _same_structure(batch[j][2], it[2]):
                g.append(i)
                break
        else:
            groups.append([i])
    out = []
    for g in groups:
        if len(g) == 1:
            out.append(_Group(batch[g[0]][0], batch[g[0]][2], (g[0],), False))
            continue
        stack = lambda *xs: jnp.stack(xs) if eqx.is_array(xs[0]) else xs[0]
        out.append(_Group(jax.tree.map(stack, *[batch[i][0] for i in g]),
                          jax.tree.map(stack, *[batch[i][2] for i in g]), tuple(g), True))
    return tuple(out)


@eqx.filter_jit
def _group_terms(controller, groups, weights):
    """`(items, 2)`: mean cost and mse over the rollouts of each item of a grouped batch."""
    parts, order = [], []
    for g in groups:
        def one(p, sc):
            return jnp.mean(rollout_terms(p, controller, sc, weights), axis=0)

        if g.stacked:
            arrays, static = eqx.partition(g.plants, eqx.is_array)
            parts.append(jax.vmap(lambda a, sc, st=static: one(eqx.combine(a, st), sc))(
                arrays, g.scenarios))
        else:
            parts.append(one(g.plants, g.scenarios)[None])
        order += list(g.index)
    terms = jnp.concatenate(parts, axis=0)
    return terms[np.argsort(np.asarray(order))]


def batch_terms(controller, batch, weights):
    """`(items, 2)`: mean cost and mse over the rollouts of each `(plant, kind, scenarios)`
    (a list of items, or the groups `group_batch` made of one)."""
    groups = batch if isinstance(batch, tuple) and batch and isinstance(batch[0], _Group) \
        else group_batch(batch)
    return _group_terms(controller, groups, weights)

