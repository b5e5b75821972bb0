"""Closed-loop tuning on the virtual printer or a fitted model: training batches, the robust
objective relative to reference designs, plant ensembles, the validation guard and `tune`."""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable, Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..closedloop import KINDS, make_scenario
from ..closedloop.checks import check_loop
from ..control._base import AbstractController
from ..control.margins import peak_sensitivity
from ..control.schedule_ff import ScheduleFF
from ..errors import ControlError
from ..printer import Printer
from ..runtime import one_shot
from .ff_init import FF_FIELDS
from .optimiser import TuneResult, minimise
from .sensitivity import model_response, ms_penalty
from .terms import batch_terms, group_batch

#: the thesis' three test scenarios, tuned for jointly and reported separately
SCENARIOS = ("tracking", "powder", "print")
#: default scenario length for tuning and evaluation, s
DURATION = 600.0
#: offset added to the seed for held-out evaluation disturbances (never used in tuning)
HELD_OUT = 10_000
#: offset added to the seed for the guard's validation disturbances
VALIDATION = 20_000


def as_kinds(kind) -> tuple[str, ...]:
    """Scenario kinds as a tuple from a name or a sequence of names; unknown ones raise."""
    kinds = (kind,) if isinstance(kind, str) else tuple(kind)
    bad = [k for k in kinds if k not in KINDS]
    if not kinds or bad:
        raise ControlError(f"tune: unknown scenario {bad[0] if bad else '(none)'!r} "
                           f"(known: {', '.join(KINDS)})")
    return kinds


def make_batches(plants, kind=SCENARIOS, *, rollouts: int = 8, duration: float = DURATION,
                 seed: int = 0, n_batches: int = 1, scenario_kw: Mapping | None = None):
    """Training batches: for each batch, a list of `(plant, kind, Scenario)` with `rollouts`
    disturbance realisations each, drawn from `seed` (keys folded with plant and kind);
    `scenario_kw` (e.g. a fitted model's `envelope` and `setpoint`) goes to `make_scenario`."""
    if not isinstance(rollouts, (int, np.integer)) or rollouts < 1:
        raise ControlError(f"tune: rollouts must be a positive integer, got {rollouts!r}")
    kinds = as_kinds(kind)
    base = jax.random.key(int(seed))
    out = []
    for b in range(n_batches):
        batch = []
        for i, p in enumerate(plants):
            for j, k in enumerate(kinds):
                key = jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(base, b), i), j)
                batch.append((p, k, make_scenario(k, p, duration, key, n_rollouts=int(rollouts),
                                                  shared=True, **dict(scenario_kw or {}))))
        out.append(batch)
    return out


def batch_cost(controller, batch, weights=None):
    """Mean closed-loop cost over every `(plant, kind, scenarios[, scale])` of a batch, each
    divided by its `scale` (default 1)."""
    terms = batch_terms(controller, group_batch([tuple(it[:3]) for it in batch]), weights)
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


@functools.cache
def robust_objective_jit():
    """`robust_objective(terms, ref, tau)` as one program (eager, the guard compiled about
    fifteen small ones), at `runtime.one_shot()` options: the same value bit for bit as eager
    (with XLA's default options the fused program differed in the last bit)."""
    return jax.jit(robust_objective, static_argnums=2, compiler_options=one_shot())


def _reference_terms(refs, batch, weights, known=None):
    """Per item, the best (smallest finite) cost and mse over the reference controllers;
    `known`: `{id(controller): terms}` already simulated on `batch` (not simulated again)."""
    known = known or {}
    vals = np.stack([known[id(c)] if id(c) in known else np.asarray(batch_terms(c, batch, weights))
                     for c in refs])
    vals = np.where(np.isfinite(vals) & (vals > 0), vals, np.inf)
    return vals, np.min(vals, axis=0)


def best_reference_terms(refs, batches, weights=None, *, with_first: bool = False
                         ) -> list[np.ndarray]:
    """Per training batch (a list of `(plant, kind, scenarios)`, as `make_batches` returns
    them), the best (smallest finite) cost and mse per item over the controllers `refs`: what
    `tune` normalises by, for its `reference_terms` (`refs`: its start, then its
    `references`). `with_first`: `(items, 4)`, the best cost and mse, then the first
    controller's own (the start's: what `tune` holds fixed where the tuned leaves do not act,
    `fixed_items`)."""
    out = []
    for b in batches:
        vals, best = _reference_terms(refs, group_batch([tuple(it[:3]) for it in b]), weights)
        out.append(np.concatenate([best, vals[0]], axis=1) if with_first else best)
    return out


def fixed_items(controller, params, batch) -> np.ndarray | None:
    """Per item `(plant, kind, scenarios)` of `batch`, True where no value of the tuned leaves
    changes the loop: the tuned `params` are a schedule feed-forward's taps
    (`ff_init.FF_FIELDS`) and the item's event schedule is zero throughout (the tracking
    scenario: no recoat, no exposure), so the taps multiply zeros and every iterate's terms
    there are the start's, exactly. None when no item is (or every one is) fixed."""
    if not isinstance(controller, ScheduleFF) or params is None or \
            not set((params,) if isinstance(params, str) else params) <= set(FF_FIELDS):
        return None
    fixed = np.asarray([it[2].s is None or not np.any(np.asarray(it[2].s)) for it in batch])
    return fixed if fixed.any() and not fixed.all() else None


def plant_ensemble(printer, n: int = 3, *, spread: float = 0.15, shift_c: float = 15.0,
                   seed: int = 0) -> list:
    """`printer` and `n` perturbed copies of it for robust tuning. Each copy scales the zone
    heat capacities, losses and heater gains by factors drawn uniformly within ±`spread` (one
    factor per quantity times a ±`spread`/3 zone-to-zone jitter), the emissivity (radiative
    loss) within ±`spread`/2, and moves the surroundings by up to ±`shift_c` °C, so that the
    input holding the bed at the window centre differs from the design model's (as with another
    powder or chamber); copies whose steady input leaves (0.1, 0.9) are redrawn. Only array
    leaves change: the copies stack into one vmapped simulation. Works for any `Printer`."""
    if not isinstance(printer, Printer):
        raise ControlError("plant_ensemble: needs a virtual printer (`Printer`)")
    if not isinstance(n, (int, np.integer)) or n < 0:
        raise ControlError(f"plant_ensemble: n must be a non-negative integer, got {n!r}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 4242]))
    out, tries = [printer], 0
    n_z = printer.zones
    # the factors are applied in NumPy (the same products as in jnp) and the steady input is
    # one compiled program for every copy: no eager op compiles once per copy
    host = lambda a: np.asarray(a) if eqx.is_array(a) else a
    cap, loss, gain, sur = (host(printer.capacity), host(printer.loss), host(printer.gain),
                            host(printer.surroundings))
    rad = printer.has("radiative_loss")
    emis = host(printer.effects["radiative_loss"]["emissivity"]) if rad else None
    dev = lambda a, like: jnp.asarray(a, like.dtype) if eqx.is_array(like) else a
    while len(out) < n + 1 and tries < 20 * (n + 1):
        tries += 1
        f = 1.0 + spread * rng.uniform(-1, 1, 3)
        jit_ = lambda: 1.0 + spread / 3 * rng.uniform(-1, 1, n_z)
        new = (cap * f[0] * jit_(), loss * f[1] * jit_(), gain * f[2] * jit_()[None, :],
               sur + shift_c * rng.uniform(-1, 1))
        p = eqx.tree_at(lambda q: (q.capacity, q.loss, q.gain, q.surroundings), printer,
                        tuple(dev(a, like) for a, like in zip(new, (
                            printer.capacity, printer.loss, printer.gain, printer.surroundings))))
        if rad:
            p = eqx.tree_at(lambda q: q.effects["radiative_loss"]["emissivity"], p,
                            dev(emis * (1.0 + 0.5 * spread * rng.uniform(-1, 1)),
                                printer.effects["radiative_loss"]["emissivity"]))
        u = np.asarray(_steady_input(p))[:n_z]
        if np.all(np.isfinite(u)) and np.all((u > 0.1) & (u < 0.9)):
            out.append(p)
    return out


@eqx.filter_jit
def _steady_input(printer):
    """`Printer.steady_input()` as one compiled program (eager, it compiles every op)."""
    return printer.steady_input()


def loop_ms(model, controller) -> float | None:
    """Peak sensitivity $M_s$ of `controller` on the linear `model` (`inf` for an unstable
    loop), or None where `peak_sensitivity` has no linear feedback form for it."""
    try:
        m = peak_sensitivity(model, controller)
    except ControlError:
        return None
    return float(m["ms"]) if m["stable"] else float("inf")


def _same_leaves(a, b) -> bool:
    """Same type, structure and leaf values (compared in NumPy: no compile)."""
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    return ta == tb and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


def guarded_choice(candidates, refs, start, batch, weights, margin, tau, ms_max=None, ms_model=None):
    """Pick among `candidates` the one with the lowest robust objective on the validation
    `batch` that beats every reference on mse (by `margin`) in every item (plant × scenario)
    it changes (an item whose mse equals the start's exactly is not judged) and does not raise
    the total cost above the start's; relax the margin to 0, then fall back
    to `start`. With `ms_max` and `ms_model`, a candidate must also keep its peak sensitivity
    on `ms_model` at or below `ms_max` (`loop_ms`; unconstrained where it cannot be computed),
    reported as `ms_constraint`."""
    start_vals = np.asarray(batch_terms(start, batch, weights))
    _, best = _reference_terms(refs, batch, weights, known={id(start): start_vals})
    seen: list = []

    def ms_of(c):
        # $M_s$ depends on the feedback form only (a `ScheduleFF`'s feedback): the iterates of
        # a taps-only tuning share it, computed once
        fb = c.feedback if isinstance(c, ScheduleFF) else c
        hit = next((m for f, m in seen if _same_leaves(f, fb)), False)
        if hit is False:
            hit = loop_ms(ms_model, c)
            seen.append((fb, hit))
        return hit

    rows = []
    for i, (it, _, c) in enumerate(candidates):
        v = np.asarray(batch_terms(c, batch, weights))
        ok = bool(np.all(np.isfinite(v)))
        obj = float(robust_objective_jit()(v, best, tau)) if ok else np.inf
        # items where the candidate's mse is the start's exactly are ones the tuned parameters
        # do not act on (a schedule feed-forward in a scenario without events): not judged
        moved = v[:, 1] != start_vals[:, 1]
        rows.append({"iteration": int(it), "objective": obj,
                     "mse_ratio_worst": float(np.max(v[moved, 1] / best[moved, 1]))
                     if ok and moved.any() else np.inf,
                     "cost_ratio": float(np.sum(v[:, 0]) / np.sum(start_vals[:, 0])) if ok
                     else np.inf,
                     "ms": ms_of(c) if ok and ms_max is not None
                     and ms_model is not None else None})

    def ms_ok(r):
        return ms_max is None or r["ms"] is None or r["ms"] <= ms_max

    chosen, level = None, None
    for m in (margin, 0.0):
        ok = [i for i, r in enumerate(rows)
              if (r["mse_ratio_worst"] <= 1.0 - m if m > 0 else r["mse_ratio_worst"] < 1.0)
              and r["cost_ratio"] <= 1.0 and ms_ok(r)]
        if ok:
            chosen, level = min(ok, key=lambda i: rows[i]["objective"]), m
            break
    info = {"candidates": rows, "chosen": None if chosen is None else rows[chosen]["iteration"],
            "margin": level, "passed": chosen is not None,
            "reference_mse": best[:, 1].tolist(), "reference_cost": best[:, 0].tolist()}
    if ms_max is not None and ms_model is not None:
        ms = rows[chosen]["ms"] if chosen is not None else ms_of(start)
        info["ms_constraint"] = {
            "ms_max": float(ms_max), "chosen_ms": ms, "computable": ms is not None,
            "satisfied": None if ms is None else bool(ms <= ms_max),
            "rejected_for_ms": [r["iteration"] for r in rows if not ms_ok(r)]}
    return (start if chosen is None else candidates[chosen][2]), info


def _penalty(ms_model, ms_max, weight) -> Callable:
    """`controller -> penalty` on its soft peak sensitivity on `ms_model` above `ms_max`
    (`sensitivity.ms_penalty`), or 0 when `weight` is 0 or the limit or model is missing."""
    if weight < 0:
        raise ControlError(f"tune: ms_weight must be >= 0, got {weight}")
    if not weight or ms_max is None or ms_model is None:
        return lambda c: 0.0
    z, G = model_response(ms_model)
    return lambda c: ms_penalty(c, z, G, float(ms_max), float(weight))


def caster(dtype: str | None) -> Callable:
    """`tree -> tree` with every floating array leaf cast to `dtype` (None: the identity);
    differentiable, so a gradient flows back to the leaves' own precision."""
    if dtype is None:
        return lambda t: t
    if dtype != "float32":
        raise ControlError(f"tune: train_dtype must be None or 'float32', got {dtype!r}")

    def cast(x):
        if not eqx.is_inexact_array(x):
            return x
        if isinstance(x, jax.core.Tracer):
            return x.astype(jnp.float32)
        # a concrete array in NumPy (the same rounding): eager, each leaf shape compiled a program
        return jax.device_put(np.asarray(x).astype(np.float32))

    return lambda t: jax.tree.map(cast, t)


def field_filter(controller, names):
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
         ms_max: float | None = None, ms_model=None,
         params: Sequence[str] | None = None, scenario_kw: Mapping | None = None,
         optimiser: str = "adam", ms_weight: float = 0.0, train_dtype: str | None = None,
         reference_terms=None,
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
    - `steps`, `lr`: iterations (at most, for L-BFGS) and learning rate (L-BFGS: largest first
      move) of `optimiser` (`"adam"` or `"lbfgs"`, `minimise`); `weights`: `closedloop.cost`
      weights.
    - `references`: designs the result must beat (with the start) in every scenario and plant;
      the robust objective is relative to the best of them in each.
    - `guard`: check the kept iterates on validation seeds (`seed + VALIDATION`) and return the
      best that beats every reference's mse by `margin` (relative) in every plant and scenario
      without raising the total cost above the start's, else the start. `validation`: the
      guard's batch (a list of `(plant, kind, scenarios)`); default fresh draws from
      `seed + VALIDATION`, or the first training batch when `scenarios` are given. `tau`:
      softness of the maximum over the relative mse.
    - `ms_max`, `ms_model`: the guard also rejects an iterate whose peak sensitivity $M_s$ on
      the linear `ms_model` exceeds `ms_max` (or whose loop there is unstable); families with
      no linear feedback form (`peak_sensitivity` raises) are not constrained. Reported in
      `guard["ms_constraint"]` (`ms_max`, `chosen_ms`, `satisfied`, `rejected_for_ms`).
      `ms_weight` > 0 adds the smooth penalty $\\mu \\max(0, \\tilde M_s - M)^2$ on the soft
      peak sensitivity on `ms_model` to the training objective (`sensitivity.ms_penalty`;
      PI families), so that the iterates stay within the limit the guard enforces.
    - `params`: names of the controller fields to tune (e.g. `("q1", "q2", "qi", "qw", "b0",
      "tau_r")` for an LQG: its weights, not its design model or operating point); default
      every array leaf.
    - `scenario_kw`: passed to `make_scenario` (a fitted model's `envelope`, `setpoint`).
    - `train_dtype`: `"float32"` runs the training rollouts (value and gradient) in single
      precision: the batches, the reference terms and the controller are cast inside the
      objective, the parameters and the optimiser stay in their own precision, and the
      reference designs, the guard's validation and any evaluation stay as they are; None
      (default): as given.
    - `reference_terms`: with `normalise`, a callable returning `best_reference_terms([controller,
      *references], scenarios, weights)` (`with_first=True`: the start's own terms too, used
      on `fixed_items`), e.g. the result of a future: Adam's step is then
      compiled on placeholders of their shape while they are simulated elsewhere (another
      thread); None: simulated here first.

    With `normalise`, the items where no tuned leaf acts (`fixed_items`: a schedule
    feed-forward's taps in the tracking scenario) enter the objective with the start's terms,
    simulated once: the same objective and gradient, a third less simulation per step on the
    printer's three scenarios.
    - `progress`: called as `progress(i, cost)` after each iteration.

    **Returns:** `TuneResult` (training costs relative to the references when normalised).
    """
    pl = [plant] if plants is None else list(plants)
    if not pl:
        raise ControlError("tune: empty plant ensemble")
    for p in pl:
        check_loop("tune", p, controller)
    if not (0.0 <= margin < 1.0):
        raise ControlError(f"tune: margin must be in [0, 1), got {margin}")
    spec = field_filter(controller, params)
    batches = scenarios if scenarios is not None else make_batches(
        pl, kind, rollouts=rollouts, duration=duration, seed=seed, n_batches=n_batches,
        scenario_kw=scenario_kw)
    # items where the tuned leaves do not act (`fixed_items`) are simulated once, not per step
    fixed = [fixed_items(controller, params, b) for b in batches] if normalise else []
    fixed = fixed if fixed and all(f is not None for f in fixed) else None
    live = batches if fixed is None else [[it for it, f in zip(b, fb) if not f]
                                          for b, fb in zip(batches, fixed)]
    batches = [group_batch([tuple(it[:3]) for it in b]) for b in batches]
    refs = [controller, *references]
    pen = _penalty(ms_model, ms_max, ms_weight)
    low = caster(train_dtype)
    if normalise:
        # the references' best cost and mse per (plant, scenario), fixed (no gradient), in
        # the order live items, then fixed ones (with the start's own terms there, which
        # every iterate shares)
        lows = [low(group_batch([tuple(it[:3]) for it in b])) for b in live] \
            if fixed is not None else [low(b) for b in batches]
        n_fixed = 0 if fixed is None else int(np.sum(fixed[0]))

        def pairs():
            if reference_terms is not None:
                got = [np.asarray(r) for r in reference_terms()]
            else:
                got = [np.concatenate([m, v[0]], axis=1) for v, m in
                       (_reference_terms(refs, b, weights) for b in batches)]
            best = [r[:, :2] for r in got]
            if not all(np.all(np.isfinite(r)) for r in best):
                raise ControlError("tune: the reference designs give no finite cost on the "
                                   "training set")
            if fixed is None:
                return [(lb, low(jax.device_put(r)), low(jax.device_put(r[:0])))
                        for lb, r in zip(lows, best)]
            own = [r[:, 2:4] if r.shape[1] == 4 else np.asarray(batch_terms(controller, b, weights))
                   for r, b in zip(got, batches)]
            return [(lb, low(jax.device_put(np.concatenate([r[~f], r[f]]))),
                     low(jax.device_put(o[f]))) for lb, r, o, f in zip(lows, best, own, fixed)]

        template = None
        if reference_terms is not None:     # the step compiles on placeholders meanwhile
            items = sum(len(g.index) for g in batches[0])
            dtype = jax.tree.leaves(batches[0][0].scenarios)[0].dtype
            template = (lows[0], low(jax.device_put(np.ones((items, 2), dtype))),
                        low(jax.device_put(np.ones((n_fixed, 2), dtype))))
        res = minimise(lambda c, br: robust_objective(
                           jnp.concatenate([batch_terms(low(c), br[0], weights), br[2]]), br[1],
                           tau) + pen(c),
                       controller, pairs if template is not None else pairs(), steps=steps,
                       lr=lr, progress=progress, snapshots=snapshots if guard else 0,
                       filter_spec=spec, method=optimiser, template=template)
    else:
        res = minimise(lambda c, b: jnp.mean(batch_terms(low(c), b, weights)[:, 0]) + pen(c),
                       controller,
                       [low(b) for b in batches], steps=steps, lr=lr, progress=progress,
                       snapshots=snapshots if guard else 0, filter_spec=spec, method=optimiser)
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
                                       seed=int(seed) + VALIDATION,
                                       scenario_kw=scenario_kw)[0])
    chosen, info = guarded_choice(res.snapshots, refs, controller, val, weights, margin, tau,
                          ms_max=ms_max, ms_model=ms_model)
    info["seconds"] = time.perf_counter() - t0
    idx = [i for i, (_, _, c) in enumerate(res.snapshots) if c is chosen]
    tuned_cost = res.snapshots[idx[0]][1] if idx else res.start_cost
    return dataclasses.replace(res, controller=chosen, tuned_cost=float(tuned_cost), guard=info,
                               seconds=res.seconds + info["seconds"])

