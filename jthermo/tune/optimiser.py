"""The generic minimiser of `tune`: Adam or L-BFGS over a controller's array leaves, positive
leaves in log space, non-finite gradients zeroed, the best finite iterate (and snapshots for a
validation guard) kept.

L-BFGS (`method="lbfgs"`) treats the training cost as the deterministic function it is (the
rollouts are a fixed batch): `lbfgs.WolfeLBFGS`, an optimistix minimiser (two-loop recursion,
weak-Wolfe line search), stepped one compiled evaluation at a time so that every accepted
iterate is kept; a run costs tens of evaluations where Adam takes hundreds of steps. The first
trial step moves no parameter by more than `lr` (relative, in log space); the search may
lengthen it.
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


def _lbfgs_iterates(objective, z, batch, steps: int, lr: float):
    """Yield `(z, cost, evaluations so far)` for the start and each L-BFGS iterate
    (`lbfgs.WolfeLBFGS`, one compiled step per evaluation), stopping after `steps` accepted
    iterations or at the solver's own stops."""
    from .lbfgs import WolfeLBFGS

    x0, unravel = jax.flatten_util.ravel_pytree(z)
    solver = WolfeLBFGS(first_move=lr)

    def fn(x, b):
        return objective(unravel(x), b), None

    step = eqx.filter_jit(lambda state, b: solver.step(fn, state.x, b, {}, state, frozenset())[1])
    state = step(solver.init(fn, x0, batch, {}, None, None, frozenset()), batch)       # the start
    yield unravel(state.x), float(state.f), 1
    for _ in range(steps):
        k = int(state.accepted)
        while not bool(state.done) and int(state.accepted) == k:
            state = step(state, batch)
        if int(state.accepted) == k:             # stopped in the search: no new iterate
            return
        yield unravel(state.x), float(state.f), int(state.evals)
        if bool(state.done):
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
      rate, L-BFGS's largest first trial move (both relative for log-space leaves).
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
