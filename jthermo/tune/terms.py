"""The lean closed loop of tuning: the cost terms (`TERMS`: tracking, uniformity, effort,
window, overshoot) and the measured-output MSE accumulated in the scan carry
(`simulate_parts`, `simulate_terms`, `rollout_terms`), weights normalised by each term's scale
(`normalised_weights`), and batches of `(plant, kind, scenarios)` grouped into one vmapped
simulation per kind and plant structure (`group_batch`, `batch_terms`, `batch_parts`)."""

from __future__ import annotations

import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..closedloop import DEFAULT_WEIGHTS, initial_state
from ..closedloop.scenarios import unlabelled
from ..closedloop.scoring import is_static_zero
from ..control._base import AbstractController
from ..errors import ControlError
from ..models._base import AbstractModel
from ..printer import Printer
from ..runtime import QUICK_COMPILE, accepted, top_level

#: the cost terms of the lean path, in the order `simulate_parts` returns them: the
#: `closedloop.cost` terms plus `overshoot` (tuning only, default weight 0)
TERMS = ("tracking", "uniformity", "effort", "window", "overshoot")
#: the overshoot term counts an excursion beyond the set point from this many smoothing widths
OVERSHOOT_MARGIN = 3.0


def _weights(weights) -> dict[str, float]:
    w = {**DEFAULT_WEIGHTS, "overshoot": 0.0}
    if weights is not None:
        bad = [k for k in weights if k not in w]
        if bad:
            raise ControlError(f"tune: unknown cost weight `{bad[0]}` "
                               f"(known: {', '.join(TERMS)})")
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


def simulate_parts(plant, controller: AbstractController, scenario, *, overshoot: bool = True,
                   smoothing: float = 0.1) -> Float[Array, 6]:
    """One closed-loop run reduced inside the scan (nothing of size T kept) to the means of the
    cost terms `TERMS` and the measured-output MSE: `[tracking, uniformity, effort, window,
    overshoot, mse]`, differentiable in the controller.

    With $e = T - r$ (true temperatures) and $s$ = `smoothing` (°C):
    tracking $\\overline{e^2}$; uniformity $\\overline{(T_i - T_j)^2}$ over grid neighbours;
    effort $\\overline{\\Delta u^2}$ (mean squared input change per sample, over T − 1 changes);
    window $\\overline{\\sigma((|e| - \\text{window})/s)}$, a smooth fraction of time outside;
    overshoot $\\overline{o^2}$ with $o = |d|\\,s\\,\\mathrm{softplus}((d\\,e - 3s)/s)$, the excursion
    beyond the set point in the direction $d = \\mathrm{sign}$ of the latest set-point change
    (of $r_0 - y_0$ before the first; 0 without any: a load scenario has none).
    `overshoot=False` leaves that term out of the scan (0). `scenario`: one unbatched
    `closedloop.Scenario`.
    """
    step, measure = _plant_functions(plant)
    x0 = initial_state(plant, scenario)
    d0 = jax.tree.map(lambda a: a[0], scenario.d)
    c0 = controller.init(measure(x0, d0)[0] + scenario.v[0], scenario.r[0])
    edges = np.asarray(scenario.edges, int).reshape(-1, 2)
    dt = scenario.r.dtype
    eps = 0.1 * smoothing
    T = scenario.r.shape[0]
    gap = scenario.r[0] - scenario.y0
    dir0 = jnp.where(jnp.abs(gap) > 1e-9, jnp.sign(gap), 0.0)

    def body(carry, inp):
        x, c, u_prev, r_prev, direction, acc = carry
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
        if overshoot:
            moved = jnp.abs(r - r_prev) > 1e-9
            direction = jnp.where(moved, jnp.sign(r - r_prev), direction)
            o = jnp.abs(direction) * smoothing * jax.nn.softplus(
                (direction * e - OVERSHOOT_MARGIN * smoothing) / smoothing)
            over = jnp.mean(o ** 2)
        else:
            over = jnp.zeros((), dt)
        acc = acc + jnp.stack([jnp.mean(e ** 2), unif, du, win, over, jnp.mean((y - r) ** 2)])
        return (step(x, u, d), c, u, r, direction, acc), None

    u_shape = jax.eval_shape(lambda: controller.step(c0, scenario.r[0], scenario.r[0])[0])
    init = (x0, c0, jnp.zeros(u_shape.shape, dt), scenario.r[0], dir0, jnp.zeros((6,), dt))
    (*_, acc), _ = jax.lax.scan(
        body, init, (jnp.arange(T), scenario.r, scenario.d, scenario.v, scenario.s))
    n = jnp.asarray([T, T, max(T - 1, 1), T, T, T], dt)
    return acc / n


def simulate_terms(plant, controller: AbstractController, scenario, weights=None, *,
                   smoothing: float = 0.1) -> Float[Array, 2]:
    """One closed-loop run reduced to `[cost, mse]` inside the scan: `cost` is
    $\\sum_i w_i\\,\\text{term}_i$ over `simulate_parts`' terms (the uniformity term only where the
    scenario has grid neighbours).

    At weights without `overshoot` (or it 0) `cost` equals
    `closedloop.cost(simulate(...), scenario, weights)`; `mse` equals
    `closedloop.metrics(...)["mse"]` (measured outputs against the set point).
    """
    w = _weights(weights)
    parts = simulate_parts(plant, controller, scenario, smoothing=smoothing,
                           overshoot=not is_static_zero(w["overshoot"]))
    used = [k for k in TERMS if k != "uniformity" or len(scenario.edges)]
    J = sum(w[k] * parts[TERMS.index(k)] for k in used)
    return jnp.stack([J, parts[-1]])


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


def _stack(*xs):
    """The leaves `xs` of the items stacked on a new leading axis; concrete arrays in NumPy (the
    same values: eager, `jnp.stack` compiled a program per leaf shape)."""
    if not eqx.is_array(xs[0]):
        return xs[0]
    if any(isinstance(x, jax.core.Tracer) or getattr(x, "weak_type", False) for x in xs) \
            or jax.dtypes.issubdtype(xs[0].dtype, jax.dtypes.extended):
        return jnp.stack(xs)
    return jax.device_put(np.stack([np.asarray(x) for x in xs]))


def group_batch(batch) -> tuple[_Group, ...]:
    """Stack the items `(plant, kind, scenarios)` of a batch that can share one vmapped
    simulation: same plant and scenario structure up to their labels (`unlabelled`), e.g. a
    `plant_ensemble` or printers of other powders in every scenario kind. One trace and one
    compilation per group instead of per item (a whole study is usually one group)."""
    batch = [(unlabelled(it[0]), it[1], unlabelled(it[2])) for it in batch]
    groups: list[list[int]] = []
    for i, it in enumerate(batch):
        for g in groups:
            j = g[0]
            if _same_structure(batch[j][0], it[0]) and _same_structure(batch[j][2], it[2]):
                g.append(i)
                break
        else:
            groups.append([i])
    out = []
    for g in groups:
        if len(g) == 1:
            out.append(_Group(batch[g[0]][0], batch[g[0]][2], (g[0],), False))
            continue
        out.append(_Group(jax.tree.map(_stack, *[batch[i][0] for i in g]),
                          jax.tree.map(_stack, *[batch[i][2] for i in g]), tuple(g), True))
    return tuple(out)


def _group_terms(controller, groups, weights, parts: bool = False):
    """`(items, 2)`: mean cost and mse over the rollouts of each item of a grouped batch
    (`parts=True`: `(items, 6)`, the mean of each term of `simulate_parts` and the mse), one
    compiled program per structure, compiled with `runtime.quick_compile()` options: tune runs
    each such evaluation program a few times per process, so compiling it faster pays
    (measured by `python benchmarks/simulate_latency_ab.py`). Inside a trace (the training step's
    loss) the plain jit is inlined there: JAX refuses compile options on a nested jit."""
    fn = _quick_group_terms() if top_level() else _plain_group_terms
    return fn(controller, groups, weights, parts)


#: XLA compile options of the evaluation program (`runtime.accepted`)
TERMS_COMPILE: dict = dict(QUICK_COMPILE)


@functools.cache
def _quick_group_terms():
    return eqx.filter_jit(_group_terms_fn, compiler_options=accepted(TERMS_COMPILE))


def _group_terms_fn(controller, groups, weights, parts: bool = False):
    out, order = [], []
    for g in groups:
        def one(p, sc):
            if parts:
                per = jax.vmap(lambda s: simulate_parts(p, controller, s))(sc)
            else:
                per = rollout_terms(p, controller, sc, weights)
            return jnp.mean(per, axis=0)

        if g.stacked:
            arrays, static = eqx.partition(g.plants, eqx.is_array)
            out.append(jax.vmap(lambda a, sc, st=static: one(eqx.combine(a, st), sc))(
                arrays, g.scenarios))
        else:
            out.append(one(g.plants, g.scenarios)[None])
        order += list(g.index)
    terms = jnp.concatenate(out, axis=0)
    return terms[np.argsort(np.asarray(order))]


_plain_group_terms = eqx.filter_jit(_group_terms_fn)


def _groups(batch):
    return batch if isinstance(batch, tuple) and batch and isinstance(batch[0], _Group) \
        else group_batch(batch)


def batch_terms(controller, batch, weights):
    """`(items, 2)`: mean cost and mse over the rollouts of each `(plant, kind, scenarios)`
    (a list of items, or the groups `group_batch` made of one)."""
    return _group_terms(controller, _groups(batch), weights)


def batch_parts(controller, batch) -> Float[Array, "items 6"]:
    """`(items, 6)`: per item of `batch` (as `batch_terms` takes it), the mean over its rollouts
    of each cost term of `TERMS` and the mse (`simulate_parts`)."""
    return _group_terms(controller, _groups(batch), None, parts=True)


def normalised_weights(weights, scales) -> dict[str, float]:
    """Weights that make each term count relative to its scale: $w_i / s_i$ for each term of
    `TERMS` (the weights as `tune` takes them), so that a cost
    $\\sum_i (w_i/s_i)\\,\\text{term}_i$ equals $\\sum_i w_i$ where every term sits at its
    scale, and each weight moves the result whatever the terms' units (°C², power², a fraction).

    **Arguments:**
    - `weights`: `{term: weight}`; terms left out keep the default (`closedloop.DEFAULT_WEIGHTS`,
      overshoot 0).
    - `scales`: `{term: scale}` (e.g. each term's value for the starting controller,
      `batch_parts`); a term without a positive finite scale keeps its weight as given.
    """
    w = _weights(weights)
    bad = [k for k in scales if k not in TERMS]
    if bad:
        raise ControlError(f"tune: unknown cost term `{bad[0]}` (known: {', '.join(TERMS)})")
    out = {}
    for k, v in w.items():
        s = float(scales.get(k, 0.0))
        out[k] = float(v) / s if np.isfinite(s) and s > 0.0 else float(v)
    return out
