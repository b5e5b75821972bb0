"""End-to-end gradient tuning of controllers over vmapped closed-loop rollouts.

The closed-loop cost over B disturbance rollouts of each test scenario, on one plant or on a
plant ensemble, is differentiated with `eqx.filter_value_and_grad` with respect to every
inexact array leaf of the controller, and minimised with optax Adam in one jitted `make_step`;
the loop over iterations and the progress report stay outside jit.

The rollouts run on a lean path (`rollout_terms`): one `lax.scan` per rollout that accumulates
the cost terms and the measured-output MSE in its carry, so no `(B, T, n)` trajectory is stored.

Robust objective (`tune(..., normalise=True)`, the default): for every plant $p$ and scenario
$k$, the mean cost $J_{pk}$ and the measured MSE $m_{pk}$ are divided by the best value any
reference design reaches there (the start and, e.g., every classical design), and

$f = \\overline{\\rho^J} + \\overline{\\rho^m}
 + \\tau \\big(\\log \\sum e^{\\rho^m/\\tau} - \\log n\\big)$,
$\\rho^J = \\log J_{pk}/J^*_{pk}$, $\\rho^m = \\log m_{pk}/m^*_{pk}$

is minimised: the mean relative improvement plus a soft maximum of the relative MSE that stops
any scenario (or plant) from being sacrificed for another. A final guard checks the iterates
kept along the way on *validation* seeds (distinct from the training seeds and from
`HELD_OUT`) and returns the best one that beats the references' MSE in every scenario on
every plant without raising the total cost; when none does it returns the starting controller.

Parameters stay valid by construction: every leaf whose entries are all positive at the start
(gains, integral times, filter time constants, LQ weights) is optimised in log space,
$\\theta = e^{z}$, so it stays positive and Adam's steps are relative; other leaves (e.g. a
decoupling matrix with signs) are optimised as they are. Non-finite gradients are zeroed, and
only finite iterates are kept, so tuning never hands back a NaN or diverging controller.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, Float

from .control._base import AbstractController
from .errors import ControlError

# ----------------------------------------------------------------------------------------
# generic minimiser over the controller's array leaves
# ----------------------------------------------------------------------------------------


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


# ----------------------------------------------------------------------------------------
# the lean closed loop: cost terms accumulated in the scan carry
# ----------------------------------------------------------------------------------------

#: the thesis' three test scenarios, tuned for jointly and reported separately
SCENARIOS = ("tracking", "powder", "print")
#: default scenario length for tuning and evaluation, s
DURATION = 600.0
#: offset added to the seed for held-out evaluation disturbances (never used in tuning)
HELD_OUT = 10_000
#: offset added to the seed for the guard's validation disturbances
VALIDATION = 20_000


def _weights(weights) -> dict[str, float]:
    from .closedloop import DEFAULT_WEIGHTS

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
    from .models._base import AbstractModel
    from .printer import Printer

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
    from .closedloop import initial_state

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
        k, r, d, v = inp
        y_clean, temps = measure(x, d)
        y = y_clean + v
        u, c = controller.step(c, y, r)
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
        body, init, (jnp.arange(T), scenario.r, scenario.d, scenario.v))
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


def _batch_terms(controller, batch, weights):
    """`(items, 2)`: mean cost and mse over the rollouts of each `(plant, kind, scenarios)`
    (a list of items, or the groups `group_batch` made of one)."""
    groups = batch if isinstance(batch, tuple) and batch and isinstance(batch[0], _Group) \
        else group_batch(batch)
    return _group_terms(controller, groups, weights)


# ----------------------------------------------------------------------------------------
# closed-loop tuning on the virtual printer or a fitted model
# ----------------------------------------------------------------------------------------


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
    """Mean closed-loop cost over every `(plant, kind, scenarios[, scale])` of a batch, each
    divided by its `scale` (default 1)."""
    terms = _batch_terms(controller, group_batch([tuple(it[:3]) for it in batch]), weights)
    scale = jnp.asarray([it[3] if len(it) > 3 else 1.0 for it in batch], terms.dtype)
    return jnp.mean(terms[:, 0] / scale)


def robust_objective(terms: Float[Array, "items 2"], ref: Float[Array, "items 2"],
                     tau: float = 0.02) -> Float[Array, ""]:
    """$\\overline{\\rho^J} + \\overline{\\rho^m} + \\tau(\\log\\sum e^{\\rho^m/\\tau} - \\log n)$
    with $\\rho = \\log(\\text{terms}/\\text{ref})$ per item (plant × scenario): the mean
    relative cost and mse plus a soft maximum of the relative mse, so that no scenario's mse is
    given up for another's. Zero at the references, negative where everything improves."""
    rho = jnp.log(terms / ref)
    rm = rho[:, 1]
    return jnp.mean(rho[:, 0]) + jnp.mean(rm) + tau * (jax.nn.logsumexp(rm / tau)
                                                       - jnp.log(rm.size))


def _reference_terms(refs, batch, weights):
    """Per item, the best (smallest finite) cost and mse over the reference controllers."""
    vals = np.stack([np.asarray(_batch_terms(c, batch, weights)) for c in refs])
    vals = np.where(np.isfinite(vals) & (vals > 0), vals, np.inf)
    return vals, np.min(vals, axis=0)


def plant_ensemble(printer, n: int = 3, *, spread: float = 0.15, shift_c: float = 15.0,
                   seed: int = 0) -> list:
    """`printer` and `n` perturbed copies of it for robust tuning. Each copy scales the zone
    heat capacities, losses and heater gains by factors drawn uniformly within ±`spread` (one
    factor per quantity times a ±`spread`/3 zone-to-zone jitter), the emissivity (radiative
    loss) within ±`spread`/2, and moves the surroundings by up to ±`shift_c` °C, so that the
    input holding the bed at the window centre differs from the design model's (as with another
    powder or chamber); copies whose steady input leaves (0.1, 0.9) are redrawn. Only array
    leaves change: the copies stack into one vmapped simulation. Works for any `Printer`."""
    from .printer import Printer

    if not isinstance(printer, Printer):
        raise ControlError("plant_ensemble: needs a virtual printer (`Printer`)")
    if not isinstance(n, (int, np.integer)) or n < 0:
        raise ControlError(f"plant_ensemble: n must be a non-negative integer, got {n!r}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 4242]))
    out, tries = [printer], 0
    n_z = printer.zones
    while len(out) < n + 1 and tries < 20 * (n + 1):
        tries += 1
        f = 1.0 + spread * rng.uniform(-1, 1, 3)
        jit_ = lambda: 1.0 + spread / 3 * rng.uniform(-1, 1, n_z)
        p = eqx.tree_at(lambda q: (q.capacity, q.loss, q.gain, q.surroundings), printer,
                        (printer.capacity * f[0] * jit_(), printer.loss * f[1] * jit_(),
                         printer.gain * f[2] * jit_()[None, :],
                         printer.surroundings + shift_c * rng.uniform(-1, 1)))
        if printer.has("radiative_loss"):
            p = eqx.tree_at(lambda q: q.effects["radiative_loss"]["emissivity"], p,
                            p.effects["radiative_loss"]["emissivity"]
                            * (1.0 + 0.5 * spread * rng.uniform(-1, 1)))
        u = np.asarray(p.steady_input())[:n_z]
        if np.all(np.isfinite(u)) and np.all((u > 0.1) & (u < 0.9)):
            out.append(p)
    return out


def _guard(candidates, refs, start, batch, weights, margin, tau):
    """Pick among `candidates` the one with the lowest robust objective on the validation
    `batch` that beats every reference on mse (by `margin`) in every item (plant × scenario)
    and does not raise the total cost above the start's; relax the margin to 0, then fall back
    to `start`."""
    _, best = _reference_terms(refs, batch, weights)
    start_vals = np.asarray(_batch_terms(start, batch, weights))
    rows = []
    for i, (it, _, c) in enumerate(candidates):
        v = np.asarray(_batch_terms(c, batch, weights))
        ok = bool(np.all(np.isfinite(v)))
        obj = float(robust_objective(jnp.asarray(v), jnp.asarray(best), tau)) if ok else np.inf
        rows.append({"iteration": int(it), "objective": obj,
                     "mse_ratio_worst": float(np.max(v[:, 1] / best[:, 1])) if ok else np.inf,
                     "cost_ratio": float(np.sum(v[:, 0]) / np.sum(start_vals[:, 0])) if ok
                     else np.inf})
    chosen, level = None, None
    for m in (margin, 0.0):
        ok = [i for i, r in enumerate(rows)
              if (r["mse_ratio_worst"] <= 1.0 - m if m > 0 else r["mse_ratio_worst"] < 1.0)
              and r["cost_ratio"] <= 1.0]
        if ok:
            chosen, level = min(ok, key=lambda i: rows[i]["objective"]), m
            break
    info = {"candidates": rows, "chosen": None if chosen is None else rows[chosen]["iteration"],
            "margin": level, "passed": chosen is not None,
            "reference_mse": best[:, 1].tolist(), "reference_cost": best[:, 0].tolist()}
    return (start if chosen is None else candidates[chosen][2]), info


def _field_filter(controller, names):
    """`eqx.partition` filter selecting the array leaves of the named fields (all: None)."""
    if names is None:
        return eqx.is_inexact_array
    names = (names,) if isinstance(names, str) else tuple(names)
    fields = {f.name for f in dataclasses.fields(controller)}
    bad = [n for n in names if n not in fields]
    if bad or not names:
        raise ControlError(f"tune: {type(controller).__name__} has no field `{bad[0]}`" if bad
                           else "tune: `params` names no field")
    spec = jax.tree.map(lambda _: False, controller)
    return eqx.tree_at(lambda c: tuple(getattr(c, n) for n in names), spec,
                       replace=tuple(jax.tree.map(eqx.is_inexact_array, getattr(controller, n))
                                     for n in names))


def tune(controller: AbstractController, plant, *, kind=SCENARIOS, scenarios=None,
         rollouts: int = 8, steps: int = 100, lr: float = 0.05,
         weights: Mapping[str, float] | None = None, seed: int = 0, plants=None,
         duration: float = DURATION, n_batches: int = 1, normalise: bool = True,
         references: Sequence[AbstractController] = (), guard: bool = True,
         margin: float = 0.01, tau: float = 0.02, snapshots: int = 10, validation=None,
         params: Sequence[str] | None = None,
         progress: Callable[[int, float], None] | None = None) -> TuneResult:
    """Tune a controller end to end on simulated closed-loop cost.

    Minimises, over `rollouts` disturbance realisations of each scenario in `kind` (default
    the thesis' three tests) on `plant` or on every plant of `plants` (an ensemble, e.g.
    `plant_ensemble`), the robust objective of the module docstring (`normalise=True`) or the
    plain mean of `closedloop.cost` (`normalise=False`). Gradients by `jax.grad` through the
    scanned simulations (the lean `rollout_terms` path).

    **Arguments:**
    - `controller`: the starting controller (a classical design; best: the best one).
    - `plant`: a `Printer` or a fitted model; ignored when `plants` is given.
    - `kind`: a scenario name or a sequence of them; `scenarios`: ready-made training batches
      (as `make_batches` returns) instead.
    - `rollouts`, `duration` (s), `n_batches`: size of the training set, drawn from `seed`.
    - `steps`, `lr`: Adam iterations and learning rate; `weights`: `closedloop.cost` weights.
    - `references`: designs the result must beat (with the start) in every scenario and plant;
      the robust objective is relative to the best of them in each.
    - `guard`: check the kept iterates on validation seeds (`seed + VALIDATION`) and return the
      best that beats every reference's mse by `margin` (relative) in every plant and scenario
      without raising the total cost above the start's, else the start. `validation`: the
      guard's batch (a list of `(plant, kind, scenarios)`); default fresh draws from
      `seed + VALIDATION`, or the first training batch when `scenarios` are given. `tau`:
      softness of the maximum over the relative mse.
    - `params`: names of the controller fields to tune (e.g. `("q1", "q2", "qi", "qw", "b0",
      "tau_r")` for an LQG: its weights, not its design model or operating point); default
      every array leaf.
    - `progress`: called as `progress(i, cost)` after each iteration.

    **Returns:** `TuneResult` (training costs relative to the references when normalised).
    """
    pl = [plant] if plants is None else list(plants)
    if not pl:
        raise ControlError("tune: empty plant ensemble")
    if not (0.0 <= margin < 1.0):
        raise ControlError(f"tune: margin must be in [0, 1), got {margin}")
    spec = _field_filter(controller, params)
    batches = scenarios if scenarios is not None else make_batches(
        pl, kind, rollouts=rollouts, duration=duration, seed=seed, n_batches=n_batches)
    batches = [group_batch([tuple(it[:3]) for it in b]) for b in batches]
    refs = [controller, *references]
    if normalise:
        # the references' best cost and mse per (plant, scenario), fixed (no gradient)
        pairs = [(b, jnp.asarray(_reference_terms(refs, b, weights)[1])) for b in batches]
        if not all(bool(jnp.all(jnp.isfinite(r))) for _, r in pairs):
            raise ControlError("tune: the reference designs give no finite cost on the training set")
        res = minimise(lambda c, br: robust_objective(_batch_terms(c, br[0], weights), br[1], tau),
                       controller, pairs, steps=steps, lr=lr, progress=progress,
                       snapshots=snapshots if guard else 0, filter_spec=spec)
    else:
        res = minimise(lambda c, b: jnp.mean(_batch_terms(c, b, weights)[:, 0]), controller,
                       batches, steps=steps, lr=lr, progress=progress,
                       snapshots=snapshots if guard else 0, filter_spec=spec)
    if not guard:
        return res
    t0 = time.perf_counter()
    if validation is not None:
        val = group_batch([tuple(it[:3]) for it in validation])
    elif scenarios is not None:      # custom scenarios: no generator to draw fresh ones from
        val = batches[0]
    else:
        sc0 = batches[0][0].scenarios
        B, T = (sc0.r.shape[1], sc0.r.shape[2]) if batches[0][0].stacked else sc0.r.shape[:2]
        val = group_batch(make_batches(pl, kind, rollouts=int(B), duration=float(T * sc0.ts),
                                       seed=int(seed) + VALIDATION)[0])
    chosen, info = _guard(res.snapshots, refs, controller, val, weights, margin, tau)
    info["seconds"] = time.perf_counter() - t0
    idx = [i for i, (_, _, c) in enumerate(res.snapshots) if c is chosen]
    tuned_cost = res.snapshots[idx[0]][1] if idx else res.start_cost
    return dataclasses.replace(res, controller=chosen, tuned_cost=float(tuned_cost), guard=info,
                               seconds=res.seconds + info["seconds"])


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
    the printer's known parameters): Jacobians of its one-sample map (`Printer.discretise`)
    at the steady state with no recoat or laser, outputs the bed sensors, operating point the
    steady input and the window-centre readings. Input delay is left out (a design model)."""
    from .models._base import StateSpace
    from .printer import PrinterState

    if printer.has_areas:
        raise ControlError("printer_model: printers with areas 1–3 are not supported here")
    x0 = printer.initial_state()
    u0 = printer.steady_input()
    disc = printer.discretise()
    d = printer.default_disturbance()

    def f(z, u):
        buf = jnp.broadcast_to(u, x0.buffer.shape)        # the delay line holds u: no delay
        return disc.step(PrinterState(z=z, buffer=buf, since=x0.since), u, d).z

    Ad = jax.jacfwd(f, 0)(x0.z, u0)
    Bd = jax.jacfwd(f, 1)(x0.z, u0)
    n = printer.n_outputs
    C = jnp.eye(Ad.shape[0], dtype=Ad.dtype)[:n]
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


def _held_out_comparison(ctrls, plant, seeds, rollouts, duration, weights) -> dict:
    """Start, tuned and lambda-PI controllers (`ctrls`) on held-out `seeds` of `plant`: their
    mean costs, `improvement_percent` = 100·(1 − tuned/lambda_pi) and per-scenario MSE/cost."""
    ev = {name: evaluate(c, plant, SCENARIOS, seeds, rollouts=rollouts, duration=duration,
                         weights=weights) for name, c in ctrls.items()}
    suffix = {"start": "before", "tuned": "after", "lambda_pi": "lambda_pi"}
    scen = {k: {f"{q}_{suffix[name]}": ev[name]["scenarios"][k][q]
                for q in ("mse", "cost") for name in ctrls} for k in SCENARIOS}
    tuned, lam_c = ev["tuned"]["cost"], ev["lambda_pi"]["cost"]
    return {"start_cost": ev["start"]["cost"], "tuned_cost": tuned, "lambda_pi_cost": lam_c,
            "improvement_percent": 100.0 * (1.0 - tuned / lam_c), "scenarios": scen}


def tune_report(controller_family: str, *, plant="printer", model=None, rollouts: int = 8,
                steps: int = 200, seed: int = 0, lr: float = 0.05, zones: int = 4,
                powder: str = "PA12", duration: float = DURATION, plant_seed: int = 0,
                eval_rollouts: int | None = None, weights=None, ensemble: int = 2,
                references: Sequence[str] = ("pi_lambda",), changed_powder: str | None = "auto",
                progress: Callable[[int, float], None] | None = None) -> dict:
    """Tune one controller family against the virtual printer and report on held-out seeds.

    Starts from the classical design of `controller_family` (see `control.design`) on `model`
    (default: the printer linearised at the window centre, `printer_model`), tunes it on
    disturbance seeds drawn from `seed` on the printer and, for a `Printer`, `ensemble`
    perturbed copies of it (`plant_ensemble`), guarded on validation seeds against the start
    and the designs named in `references` (families designed on the same model), and evaluates
    start, tuned and the lambda-tuned diagonal PI on the held-out seed `seed + HELD_OUT` in
    the three scenarios; for the built-in printer also on the printer with `changed_powder`
    (`"auto"`: PA11 when tuned on PA12, else PA12; None: skip), which tuning never saw.

    **Returns:** a JSON-ready dict with `controller`, `start_cost`, `tuned_cost`,
    `lambda_pi_cost`, `improvement_percent` (100·(1 − tuned/lambda_pi)), `scenarios`
    (per-scenario MSE and cost before/after, and of the lambda PI), `changed_powder` (the same
    figures on the other powder, or None), `history`, `seconds`, and
    the tuned controller under the key `"tuned"` (not JSON: pop it before writing).
    """
    from .control.design import design
    from .models._base import AbstractModel
    from .printer import Printer

    t0 = time.perf_counter()
    pl = _plant_from(plant, zones=zones, powder=powder, plant_seed=plant_seed)
    if changed_powder == "auto":
        changed_powder = "PA11" if powder != "PA11" else "PA12"
    if model is None:
        model = pl if isinstance(pl, AbstractModel) else printer_model(pl)
    start = design(controller_family, model)
    lam_pi = design("pi_lambda", model)
    refs = [design(f, model) for f in references if f != controller_family]
    plants = plant_ensemble(pl, ensemble, seed=plant_seed) if isinstance(pl, Printer) and \
        ensemble else [pl]
    res = tune(start, pl, plants=plants, rollouts=rollouts, steps=steps, lr=lr, seed=seed,
               duration=duration, weights=weights, references=refs, progress=progress)
    seeds = (int(seed) + HELD_OUT,)
    er = eval_rollouts or rollouts
    ctrls = {"start": start, "tuned": res.controller, "lambda_pi": lam_pi}
    held = _held_out_comparison(ctrls, pl, seeds, er, duration, weights)
    changed = None
    if isinstance(plant, str) and changed_powder:
        # the same controllers on the printer with the other powder, never seen in tuning
        other = _plant_from("printer", zones=zones, powder=changed_powder, plant_seed=plant_seed)
        changed = {"powder": changed_powder,
                   **_held_out_comparison(ctrls, other, seeds, er, duration, weights)}
    return {"controller": controller_family, **held,
            "changed_powder": changed,
            "train_start_cost": res.start_cost, "train_tuned_cost": res.tuned_cost,
            "guard": {k: v for k, v in (res.guard or {}).items() if k != "candidates"},
            "ensemble": len(plants),
            "history": [float(h) for h in res.history], "rollouts": int(rollouts),
            "steps": int(steps), "seed": int(seed), "held_out_seeds": list(seeds),
            "duration": float(duration), "zones": int(getattr(pl, "zones", 0) or 0),
            "powder": powder, "seconds": time.perf_counter() - t0, "tuned": res.controller}
