"""The generic minimiser of `tune`: Adam or L-BFGS over a controller's array leaves, positive
leaves in log space, non-finite gradients zeroed, the best finite iterate (and snapshots for a
validation guard) kept.

L-BFGS (`method="lbfgs"`) treats the training cost as the deterministic function it is (the
rollouts are a fixed batch): direction $d = -H g$ by the two-loop recursion over the last
`memory` pairs $s_k = z_{k+1} - z_k$, $y_k = g_{k+1} - g_k$ with $H_0 = (s^\\top y / y^\\top
y) I$ (Nocedal & Wright 2006, Alg. 7.4), and a weak-Wolfe bracketing line search
($f(z + \\alpha d) \\le f + c_1 \\alpha g^\\top d$, $\\nabla f(z + \\alpha d)^\\top d \\ge c_2
g^\\top d$; Lewis & Overton 2013) on one compiled value-and-gradient, so a run costs tens of
evaluations where Adam takes hundreds of steps. The first step is scaled so that no parameter
moves by more than `lr` (relative, in log space).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from ..control._base import AbstractController
from ..errors import ControlError
from ..runtime import QUICK_COMPILE, accepted

#: XLA compile options of Adam's training-step program (`runtime.accepted`; empty: XLA's
#: defaults): `runtime.QUICK_COMPILE` (XLA's older CPU fusion emitters) compiles the default
#: `jthermo tune` step in less CPU time for lqg and pi, at the same CPU time per step
STEP_COMPILE: dict = dict(QUICK_COMPILE)


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
    evaluations: int = 0         # gradient evaluations of the training cost
    method: str = "adam"         # `minimise`'s method

    def __repr__(self) -> str:
        """The returned controller with its gains, the costs and the guard's verdict (not the
        snapshots: they hold one controller per kept iterate)."""
        verdict = ("not run" if self.guard is None else "passed" if self.guard.get("passed")
                   else "failed: the start is returned")
        return (f"TuneResult: training cost {self.start_cost:.4g} -> {self.tuned_cost:.4g} over "
                f"{len(self.history)} iterations, guard {verdict}, {self.seconds:.3g} s\n"
                f"  controller: {self.controller!r}")


def _log_mask(params):
    """True for leaves optimised in log space (all entries positive at the start)."""
    return jax.tree_util.tree_map(lambda x: bool(np.all(np.asarray(x) > 0)), params)


def _to_z(params, mask):
    return jax.tree_util.tree_map(lambda x, m: jnp.log(x) if m else x, params, mask)


def _from_z(z, mask):
    return jax.tree_util.tree_map(lambda v, m: jnp.exp(v) if m else v, z, mask)


def _finite_tree(tree) -> bool:
    """Every leaf finite, checked in NumPy (eager `jnp` compiled two programs per leaf shape)."""
    return all(bool(np.all(np.isfinite(np.asarray(x)))) for x in jax.tree_util.tree_leaves(tree))


#: minimise's methods
METHODS = ("adam", "lbfgs")


def lbfgs_direction(g: np.ndarray, pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """$-H g$ by the L-BFGS two-loop recursion over the curvature `pairs` $(s, y)$, oldest
    first, with $H_0 = (s^\\top y / y^\\top y) I$ from the newest pair ($-g$ without pairs)."""
    q = np.array(g, np.float64)
    alphas = []
    for s, y in reversed(pairs):
        a = (s @ q) / (y @ s)
        q -= a * y
        alphas.append(a)
    if pairs:
        s, y = pairs[-1]
        q *= (s @ y) / (y @ y)
    for (s, y), a in zip(pairs, reversed(alphas)):
        q += s * (a - (y @ q) / (y @ s))
    return -q


def wolfe_search(vg: Callable[[np.ndarray], tuple[float, np.ndarray]], z: np.ndarray, f0: float,
                 g0: np.ndarray, d: np.ndarray, *, c1: float = 1e-4, c2: float = 0.9,
                 max_evals: int = 10):
    """Weak-Wolfe step along the descent direction `d` from `z` (cost `f0`, gradient `g0`):
    bisect between a step too long (Armijo fails or the cost is not finite) and one too short
    (the slope still below $c_2 g_0^\\top d$), doubling while none is too long.

    **Returns:** `(z, f, g, evaluations)` at the accepted step, or at the longest Armijo step
    seen when the budget runs out; `(None, f0, g0, evaluations)` when no step decreases."""
    slope = float(g0 @ d)
    lo, hi, alpha, best = 0.0, np.inf, 1.0, None
    for n in range(1, max_evals + 1):
        zt = z + alpha * d
        f, g = vg(zt)
        if not np.isfinite(f) or f > f0 + c1 * alpha * slope:
            hi = alpha
        else:
            best = (zt, f, g)
            if float(g @ d) >= c2 * slope:
                return zt, f, g, n
            lo = alpha
        alpha = 0.5 * (lo + hi) if np.isfinite(hi) else 2.0 * lo
    return (*best, max_evals) if best is not None else (None, f0, g0, max_evals)


def _flat_value_and_grad(objective, z, batch):
    """`(vg(x) -> (float, ndarray), x0, unravel)`: the objective at the flattened parameters,
    compiled once, with a non-finite cost read as `inf` and non-finite gradients zeroed."""
    x0, unravel = jax.flatten_util.ravel_pytree(z)

    @jax.jit
    def vg(x, b):
        v, g = jax.value_and_grad(lambda xx: objective(unravel(xx), b))(x)
        return v, jnp.where(jnp.isfinite(g), g, 0.0)

    def call(x):
        v, g = vg(jnp.asarray(x), batch)
        v = float(v)
        return (v if np.isfinite(v) else np.inf), np.asarray(g, np.float64)

    return call, np.asarray(x0, np.float64), unravel


def _lbfgs_iterates(objective, z, batch, steps: int, lr: float, memory: int = 10,
                    ftol: float = 1e-9, gtol: float = 1e-8):
    """Yield `(z, cost, evaluations so far)` for the start and each L-BFGS iterate, stopping
    after `steps` iterations, when the relative decrease falls below `ftol`, the gradient
    below `gtol` (max norm) or the line search finds no decrease."""
    vg, x, unravel = _flat_value_and_grad(objective, z, batch)
    f, g = vg(x)
    evals, pairs = 1, []
    yield unravel(jnp.asarray(x)), f, evals
    for _ in range(steps):
        if not np.isfinite(f) or np.max(np.abs(g)) < gtol:
            return
        d = lbfgs_direction(g, pairs)
        if not pairs:                     # first step: no parameter moves by more than lr
            d *= lr / max(float(np.max(np.abs(d))), 1e-300)
        x_new, f_new, g_new, n = wolfe_search(vg, x, f, g, d)
        evals += n
        if x_new is None:
            return
        s, y = x_new - x, g_new - g
        if s @ y > 1e-12 * np.sqrt((s @ s) * (y @ y)):
            pairs = [*pairs, (s, y)][-memory:]
        done = f - f_new <= ftol * max(abs(f), 1.0)
        x, f, g = x_new, f_new, g_new
        yield unravel(jnp.asarray(x)), f, evals
        if done:
            return


def adam_iterates(objective, z, batches: Callable[[], list], steps: int, lr: float,
                   template=None):
    """Yield `(z, cost of z on its batch, evaluations so far)` for each Adam iterate (the
    batches, which `batches()` returns, cycled), then the last finite iterate with its cost on
    the first batch (evaluations None). With a `template` batch, the step is compiled (and run
    once, its result unused) on it before `batches()` is called."""
    import optax  # here, not at import: `jthermo simulate` imports tune for its design model

    opt = optax.adam(lr)
    opt_state = opt.init(eqx.filter(z, eqx.is_inexact_array))

    def make_step(z, opt_state, batch):
        val, grads = eqx.filter_value_and_grad(objective)(z, batch)
        grads = jax.tree_util.tree_map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grads)
        updates, opt_state = opt.update(grads, opt_state, z)
        return eqx.apply_updates(z, updates), opt_state, val

    make_step = eqx.filter_jit(make_step, compiler_options=accepted(STEP_COMPILE) or None)
    if template is not None:
        jax.block_until_ready(make_step(z, opt_state, template))
    batches = batches()
    for i in range(steps):
        z_new, opt_state, val = make_step(z, opt_state, batches[i % len(batches)])
        yield z, float(val), i + 1
        if not _finite_tree(z_new):
            break
        z = z_new
    # the last iterate has not been evaluated yet; with several batches judge all on batch 0
    # (by the compiled step itself, its update unused: no second program to compile)
    yield z, float(make_step(z, opt_state, batches[0])[2]), None


def minimise(loss: Callable[[Any, Any], jax.Array], controller, batches: Sequence[Any], *,
             steps: int = 100, lr: float = 0.05, progress: Callable[[int, float], None] | None
             = None, filter_spec=eqx.is_inexact_array, snapshots: int = 0,
             method: str = "adam", template=None) -> TuneResult:
    """Minimise `loss(controller, batch)` over the controller's array leaves with Adam or
    L-BFGS (module docstring).

    **Arguments:**
    - `loss`: scalar, differentiable; `batch` is any pytree (scenarios, plants) that it reads.
    - `batches`: training batches, all of the same shapes so that the step compiles once;
      Adam cycles through them (one per iteration), L-BFGS minimises their mean. Or a callable
      returning them, called once Adam's step is compiled on `template` (a batch of their
      shapes and dtypes, e.g. placeholder values; the step is run on it once and the result
      dropped), so that they can be computed elsewhere (another thread) meanwhile; L-BFGS
      calls it first.
    - `steps`: iterations (L-BFGS: at most; it stops at convergence). `lr`: Adam's learning
      rate, L-BFGS's largest first move (both relative for log-space leaves).
    - `progress`: called as `progress(i, cost)` after each iteration (outside jit).
    - `snapshots`: keep about this many finite iterates along the way (plus the start, the
      best and the last) in `TuneResult.snapshots`, for a validation guard.
    - `method`: `"adam"` or `"lbfgs"`.

    **Returns:** `TuneResult` with the best finite iterate (by training cost).
    """
    if not isinstance(steps, (int, np.integer)) or steps < 0:
        raise ControlError(f"tune: steps must be >= 0, got {steps}")
    if not callable(batches) and not batches:
        raise ControlError("tune: no training batch")
    if method not in METHODS:
        raise ControlError(f"tune: unknown optimiser {method!r} (known: {', '.join(METHODS)})")
    t0 = time.perf_counter()
    params, static = eqx.partition(controller, filter_spec)
    mask = _log_mask(params)
    z0 = _to_z(params, mask)

    def objective(z, batch):
        return loss(eqx.combine(_from_z(z, mask), static), batch)

    got: list = []

    def resolved() -> list:
        if not got:
            b = list(batches() if callable(batches) else batches)
            if not b:
                raise ControlError("tune: no training batch")
            got.append(b)
        return got[0]

    if method == "lbfgs":
        bs = resolved()
        many = len(bs) > 1
        obj = (lambda z, bb: sum(objective(z, b) for b in bb) / len(bb)) if many else objective
        its = _lbfgs_iterates(obj, z0, tuple(bs) if many else bs[0], steps, lr)
    else:
        its = adam_iterates(objective, z0, resolved, steps, lr, template=template)
    iterates, evals = [], 0           # (z_k, f_k), k = 0..K; f_K of Adam on batches[0]
    for z, val, n in its:
        if not iterates and not np.isfinite(val):
            raise ControlError("tune: the starting controller gives a non-finite cost")
        if iterates and progress is not None:
            progress(len(iterates) - 1, iterates[-1][1])
        iterates.append((z, val))
        evals = n or evals
    return _result(iterates, evals, method, snapshots,
                   comparable=method == "lbfgs" or len(resolved()) == 1,
                   rebuild=lambda zz: eqx.combine(_from_z(zz, mask), static), t0=t0)


def _result(iterates, evals, method, snapshots, *, comparable, rebuild, t0) -> TuneResult:
    """`TuneResult` from the iterates `(z_k, f_k)`: the best finite one when the costs are
    `comparable` (one batch), else the last when finite and no worse than the start; about
    `snapshots` of them kept (the start, every `K // snapshots`-th of the K iterations, the
    last, the best)."""
    (z0, start), (z_last, f_last) = iterates[0], iterates[-1]
    if comparable:
        k = min((i for i, (_, f) in enumerate(iterates) if np.isfinite(f)),
                key=lambda i: iterates[i][1])
        best_z, best_val = iterates[k]
    else:
        best_z, best_val = (z_last, f_last) if np.isfinite(f_last) and f_last <= start \
            else (z0, start)
    kept = []
    if snapshots:
        last = len(iterates) - 1
        every = max(1, last // snapshots)
        kept = [(k, f, z) for k, (z, f) in enumerate(iterates)
                if np.isfinite(f) and (k % every == 0 or k == last)]
        kept = [r for i, r in enumerate(kept) if all(r[2] is not q[2] for q in kept[:i])]
        if all(z is not best_z for _, _, z in kept):
            kept.append((-1, best_val, best_z))
    return TuneResult(controller=rebuild(best_z),
                      history=np.asarray([f for _, f in iterates[:-1]]), start_cost=start,
                      tuned_cost=float(best_val), seconds=time.perf_counter() - t0,
                      snapshots=tuple((k, f, rebuild(z)) for k, f, z in kept),
                      evaluations=int(evals), method=method)
