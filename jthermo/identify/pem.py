"""Generic prediction-error minimisation (PEM) engine shared by every model family.

A family supplies `residual_fn(theta, args) -> (T, ny)` (one-step prediction errors, or
simulation errors for output-error models) and a start point; this module minimises the
mean squared residual

$$V(\\theta) = \\frac{1}{T n_y} \\sum_t \\| \\varepsilon(t, \\theta) \\|^2$$

(Ljung 1999, eq. 7.11) with optimistix' Levenberg–Marquardt or Gauss–Newton, or with optax'
Adam for problems too large for a dense Jacobian. Several start points are solved together
under `jax.vmap` (`throw=False`) and the best finite one is kept. The parameter covariance is
the Gauss–Newton one (Ljung 1999, §9.3):

$$\\operatorname{Cov}\\hat\\theta = \\hat\\sigma^2 (J^\\top J)^{-1}, \\qquad
  \\hat\\sigma^2 = \\frac{\\sum \\varepsilon^2}{T n_y - p}.$$

Compilation: the whole solve (all starts, selection, covariance) is one `eqx.filter_jit`
function. It compiles once per (residual function, shapes, options); pass a module-level
function (not a fresh lambda per call) as `residual_fn` and put the data in `args`. A solve's
step limit is a traced budget (`_Budgeted`), so the screening of several starts and the best
start's solve to convergence run through one compiled solver in `batch="map"`, not two.

Record lengths from a small set: the residual's length $T$ is padded up to `bucket(T)` (four
steps per octave: at most 25 % more samples), every array of `args` whose time axis has $T$
samples extended by repeating its last sample, and the residuals past $T$ masked to zero, the
mean taken over the $T n_y$ true ones. A residual that is causal in its data (the error at $t$
depends on samples up to $t$: every prediction or simulation error is) is then the same at
every $t < T$, so the criterion, its Jacobian, the solve and the covariance are those of the
unpadded record to round-off (`padding.py`), and a process that fits records of many lengths compiles one
solve per bucket instead of one per length (`tests/identify/test_pem_padding.py`).
"""

from __future__ import annotations

from typing import Any, Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optax
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from .. import runtime
from ..errors import ConfigError, FitError
from .padding import masked_residual, padded, true_count, true_length

SOLVERS = ("lm", "gn", "adam")

#: a solve that stops at `max_steps` still counts as converged when the Gauss–Newton step from
#: its point would lower the cost by less than this fraction (MATLAB pem: 0.01 %)
EXPECTED_IMPROVEMENT_TOL = 1e-4

ResidualFn = Callable[[Float[Array, " p"], Any], Float[Array, "T ny"]]

class PEMResult(eqx.Module):
    """Outcome of `minimize`.

    **Fields:**
    - `theta`: the best parameter vector `(p,)`.
    - `cost`: its mean squared prediction error $V(\\hat\\theta)$.
    - `converged`: the solver reported success for the best start (Adam: finite cost), or the
      Gauss–Newton step from the returned point would lower the cost by less than 0.01 %
      (MATLAB pem's stopping rule; computed with the covariance).
    - `n_steps`: solver steps taken from the best start.
    - `start_costs`: final cost reached from each start point, `(K,)` (`inf` where not finite).
    - `covariance`: $\\hat\\sigma^2 (J^\\top J)^{+}$, `(p, p)` (NaN-free pseudo-inverse).
    - `std`: standard deviations of the parameters, `(p,)`.
    - `best_start`: index of the kept start point.
    - `start_steps`: solver steps taken from each start point, `(K,)`.
    - `expected_improvement`: relative cost decrease the Gauss–Newton step from `theta` would
      give, $g^\\top (J^\\top J)^{+} g / \\|\\varepsilon\\|^2$ with $g = J^\\top \\varepsilon$ (NaN
      without `covariance`).
    """

    theta: Float[Array, " p"]
    cost: Float[Array, ""]
    converged: Bool[Array, ""]
    n_steps: Int[Array, ""]
    start_costs: Float[Array, " K"]
    covariance: Float[Array, "p p"]
    std: Float[Array, " p"]
    best_start: Int[Array, ""]
    start_steps: Int[Array, " K"]
    expected_improvement: Float[Array, ""]


def _cost(residual_fn, theta, args, n_valid):
    r = residual_fn(theta, args)
    return jnp.sum(r**2) / true_count(r, n_valid)


class _Budgeted(optx.AbstractLeastSquaresSolver):
    """`inner` stopped after `options["budget"]` steps, a traced count (at most the solve's
    static `max_steps`): one compiled solver serves solves of different lengths (the
    screening's short solves and the best start's long one). A solve stopped by its budget
    ends as one stopped by `max_steps` (`nonlinear_max_steps_reached`, not successful); a
    budget of 0 returns its start point."""

    inner: optx.AbstractLeastSquaresSolver
    rtol: float
    atol: float
    norm: Callable

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        return self.inner.init(fn, y, args, options, f_struct, aux_struct, tags), jnp.array(0)

    def step(self, fn, y, args, options, state, tags):
        y, inner, aux = self.inner.step(fn, y, args, options, state[0], tags)
        return y, (inner, state[1] + 1), aux

    def terminate(self, fn, y, args, options, state, tags):
        done, result = self.inner.terminate(fn, y, args, options, state[0], tags)
        over = state[1] >= options["budget"]
        result = optx.RESULTS.where(done | ~over, result, optx.RESULTS.nonlinear_max_steps_reached)
        return done | over, result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return self.inner.postprocess(fn, y, aux, args, options, state[0], tags, result)


def _solve_one(residual_fn, theta0, args, n_valid, solver: str, max_steps: int, rtol: float,
               atol: float, learning_rate: float, budget=None):
    """Minimise from one start point; returns (theta, converged, n_steps). Vmappable.
    `residual_fn` is already masked to the first `n_valid` rows (`_minimize_impl`); `budget`:
    the steps this start may take (a traced count, at most `max_steps`; default `max_steps`;
    not for Adam)."""
    if solver == "adam":
        opt = optax.adam(learning_rate)
        loss = lambda th: _cost(residual_fn, th, args, n_valid)  # noqa: E731

        def body(carry, _):
            th, st, best_th, best_l = carry
            val, g = jax.value_and_grad(loss)(th)
            better = jnp.isfinite(val) & (val < best_l)
            best_th = jnp.where(better, th, best_th)
            best_l = jnp.where(better, val, best_l)
            upd, st = opt.update(g, st, th)
            return (optax.apply_updates(th, upd), st, best_th, best_l), None

        init = (theta0, opt.init(theta0), theta0, jnp.asarray(jnp.inf, theta0.dtype))
        (th, _, best_th, best_l), _ = jax.lax.scan(body, init, None, length=max_steps)
        last = loss(th)
        use_last = jnp.isfinite(last) & (last < best_l)
        theta = jnp.where(use_last, th, best_th)
        return theta, jnp.isfinite(jnp.minimum(last, best_l)), jnp.asarray(max_steps)

    def fn(theta, a):
        r = residual_fn(theta, a)
        # scaled so that 0.5 * ||fn||^2 = V / 2: tolerances then do not depend on T
        return jnp.reshape(r, (-1,)) / jnp.sqrt(true_count(r, n_valid))

    # Jacobi scaling at the start point (Marquardt 1963; MINPACK's `diag`): solve for
    # phi = d * theta with d the column norms of the start's Jacobian, so that every direction
    # has unit curvature. optimistix' damping (J'J + lambda I) then acts like Marquardt's
    # lambda diag(J'J): parameters with tiny sensitivity (a pole behind a near-zero gain) are no
    # longer crawled towards in tiny steps, and the tolerances are in units of that sensitivity.
    d = jnp.sqrt(jnp.sum(jax.jacfwd(fn)(theta0, args) ** 2, axis=0))
    ok_d = jnp.isfinite(d) & (d > 0)
    d = jnp.where(ok_d, d, 1.0)
    # bounded to a 100x range: a parameter with (almost) no effect on the residual, e.g. the
    # pole behind a gain that is zero in truth, would otherwise get a huge step scale and the
    # solver would wander along its flat valley until max_steps
    d = jnp.maximum(d, 1e-2 * jnp.max(d))
    scaled = lambda phi, a: fn(phi / d, a)  # noqa: E731
    if solver == "lm":
        # the damped normal equations (J'J + lambda I) are positive definite: a Cholesky solve of
        # the p x p system is far cheaper than the default QR of the (T ny + p) x p stack
        s = optx.LevenbergMarquardt(rtol=rtol, atol=atol,
                                    linear_solver=lx.Normal(lx.Cholesky()))
    else:
        s = optx.GaussNewton(rtol=rtol, atol=atol)
    s = _Budgeted(s, s.rtol, s.atol, s.norm)
    budget = jnp.asarray(max_steps if budget is None else budget)
    sol = optx.least_squares(scaled, s, theta0 * d, args, options={"budget": budget},
                             max_steps=max_steps, throw=False)
    ok = sol.result == optx.RESULTS.successful
    theta = jnp.where(budget > 0, sol.value / d, theta0)     # exactly the start at budget 0
    return theta, ok, jnp.asarray(sol.stats["num_steps"])


def _minimize_impl(residual_fn, theta0, args, n_valid, solver, max_steps, rtol, atol,
                   learning_rate, covariance, batch="vmap", screen_steps=0):
    """All starts `(K, p)`, best pick and covariance. Pure; vmappable over problems.

    With `0 < screen_steps < max_steps` and K > 1 the starts are solved for `screen_steps`
    steps only, and the best of them is then solved to convergence (successive halving down
    to one start): the cost of a multi-start is then about K * screen_steps steps plus one
    solve, instead of K times the slowest start's solve. Only the first `n_valid` residual
    rows count (a traced scalar: records padded to one length share the program).
    """
    raw = residual_fn
    if n_valid is None:
        n_valid = eqx.filter_eval_shape(raw, theta0[0], args).shape[0]

    def residual_fn(th, a):
        return masked_residual(raw, th, a, n_valid)

    def solve(th0, steps, budgets=None):
        b = jnp.full(th0.shape[0], steps) if budgets is None else budgets
        one = lambda th, bi: _solve_one(residual_fn, th, args, n_valid, solver,  # noqa: E731
                                        steps, rtol, atol, learning_rate,
                                        None if solver == "adam" else bi)
        if batch == "vmap":
            return jax.vmap(one)(th0, b)
        return jax.lax.map(lambda x: one(*x), (th0, b))

    def scored(thetas):
        costs = jax.vmap(lambda th: _cost(residual_fn, th, args, n_valid))(thetas)
        finite = jnp.isfinite(costs) & jnp.all(jnp.isfinite(thetas), axis=1)
        return jnp.where(finite, costs, jnp.inf)

    K = theta0.shape[0]
    if K > 1 and 0 < screen_steps < max_steps and solver != "adam" and batch == "map":
        # the screening and the best start's solve as two rounds of one mapped solve, each
        # start with its budget (round 0: `screen_steps` each; round 1: the rest of
        # `max_steps` for the best, 0 for the others): one solver in the program, not two
        rest = max_steps - screen_steps

        def round_(i, carry):
            thetas, oks, steps = carry
            lead = jnp.argmin(scored(thetas))
            budgets = jnp.where(i == 0, screen_steps, jnp.where(jnp.arange(K) == lead, rest, 0))
            th, ok, st = solve(thetas, max_steps, budgets)
            ran = budgets > 0
            return jnp.where(ran[:, None], th, thetas), jnp.where(ran, ok, oks), steps + st

        zeros = jnp.zeros(K, jnp.asarray(0).dtype)
        thetas, oks, steps = jax.lax.fori_loop(0, 2, round_, (theta0, zeros > 0, zeros))
    elif K > 1 and 0 < screen_steps < max_steps and solver != "adam":
        thetas, oks, steps = solve(theta0, screen_steps)
        lead = jnp.argmin(scored(thetas))
        th, ok, st = _solve_one(residual_fn, thetas[lead], args, n_valid, solver,
                                max_steps - screen_steps, rtol, atol, learning_rate)
        thetas = thetas.at[lead].set(th)
        oks = oks.at[lead].set(ok)
        steps = steps.at[lead].add(st)
    else:
        thetas, oks, steps = solve(theta0, max_steps)
    costs = scored(thetas)
    best = jnp.argmin(costs)
    theta = thetas[best]
    cost = costs[best]
    p = theta.shape[0]
    converged = oks[best]
    if covariance:
        r2 = residual_fn(theta, args)
        n = true_count(r2, n_valid)
        r = jnp.reshape(r2, (-1,))
        J = jax.jacfwd(lambda th: jnp.reshape(residual_fn(th, args), (-1,)))(theta)
        H_pinv = jnp.linalg.pinv(J.T @ J, hermitian=True)
        sigma2 = jnp.sum(r**2) / jnp.maximum(n - p, 1.0)
        cov = sigma2 * H_pinv
        cov = jnp.where(jnp.isfinite(cov), cov, jnp.inf)
        std = jnp.sqrt(jnp.clip(jnp.diagonal(cov), 0.0))
        g = J.T @ r
        improvement = (g @ H_pinv @ g) / jnp.sum(r**2)
        converged = converged | (improvement < EXPECTED_IMPROVEMENT_TOL)
    else:
        cov = jnp.full((p, p), jnp.nan, theta.dtype)
        std = jnp.full((p,), jnp.nan, theta.dtype)
        improvement = jnp.asarray(jnp.nan, theta.dtype)
    return PEMResult(theta=theta, cost=cost, converged=converged, n_steps=steps[best],
                     start_costs=costs, covariance=cov, std=std, best_start=best,
                     start_steps=steps, expected_improvement=improvement)


_minimize_jit = eqx.filter_jit(_minimize_impl)


@eqx.filter_jit
def minimize_many_jit(residual_fn, theta0, args, solver, max_steps, rtol, atol, learning_rate,
                      covariance, batch, screen_steps=0, n_valid=None):
    """`minimize_many`'s compiled solve; `n_valid`: the true record length of padded `args`
    (None: every residual row counts)."""
    def one(th, a):
        return _minimize_impl(residual_fn, th, a, n_valid, solver, max_steps, rtol, atol,
                              learning_rate, covariance, batch, screen_steps)

    if batch == "vmap":
        return eqx.filter_vmap(one)(theta0, args)
    arrays, static = eqx.partition(args, eqx.is_array)
    return jax.lax.map(lambda x: one(x[0], eqx.combine(x[1], static)), (theta0, arrays))


def check_start(theta0, solver, max_steps, batch_dims, batch="vmap"):
    if batch not in ("vmap", "map"):
        raise ConfigError(f"minimize: batch must be 'vmap' or 'map', got {batch!r}")
    if solver not in SOLVERS:
        raise ConfigError(f"minimize: solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
    if int(max_steps) < 1:
        raise ConfigError(f"minimize: max_steps must be >= 1, got {max_steps}")
    # checked in NumPy and placed by a transfer: eager jnp ops would compile per shape
    theta0 = np.asarray(theta0)
    if not np.issubdtype(theta0.dtype, np.floating):
        theta0 = theta0.astype(float)
    if theta0.ndim == batch_dims + 1:
        theta0 = np.expand_dims(theta0, batch_dims)
    if theta0.ndim != batch_dims + 2 or theta0.shape[-1] == 0:
        raise ConfigError(f"minimize: start points must have shape {'(M, ' * batch_dims}(K, p) "
                          f"or (p,), got {theta0.shape}")
    if not bool(np.all(np.isfinite(theta0))):
        raise FitError("minimize: a start point is not finite")
    return jax.device_put(theta0)


def minimize(residual_fn: ResidualFn, theta0: Float[Array, "*K p"], args: Any = None, *,
             solver: str = "lm", max_steps: int = 200, rtol: float = 1e-8, atol: float = 1e-8,
             learning_rate: float = 1e-2, covariance: bool = True, throw: bool = True,
             batch: str = "vmap", screen_steps: int = 0, pad: bool = True) -> PEMResult:
    """Minimise the mean squared residual of `residual_fn` from one or several start points.

    $\\hat\\theta = \\arg\\min_\\theta \\frac{1}{T n_y}\\sum_t \\|\\varepsilon(t,\\theta)\\|^2$
    (Ljung 1999, §7.3).

    **Arguments:**
    - `residual_fn`: `(theta (p,), args) -> (T, ny)` residuals; a module-level function so the
      compiled solve is reused between calls (a new lambda each call recompiles).
    - `theta0`: one start `(p,)` or a batch `(K, p)`, solved together with `jax.vmap`.
    - `args`: data passed through to `residual_fn` (arrays are traced, not baked in).
    - `solver`: `"lm"` (Levenberg–Marquardt), `"gn"` (Gauss–Newton) or `"adam"` (optax, a fixed
      `max_steps` steps of size `learning_rate`, for problems too large for a dense Jacobian).
    - `max_steps`, `rtol`, `atol`: solver limits and tolerances (optimistix meaning).
    - `covariance`: compute the Gauss–Newton covariance (needs the `(T·ny, p)` Jacobian).
    - `throw`: raise `FitError` when no start point gives a finite cost.
    - `batch`: `"vmap"` solves the starts together (best on an accelerator); `"map"` solves them
      one after another inside the same compiled call (`lax.map`), which is faster on CPU,
      where a vmapped trust-region loop runs every start until the slowest one stops.
    - `screen_steps`: with several starts, solve each for this many steps only and then solve
      the best one to convergence (0: solve every start to convergence).
    - `pad`: pad the record to `bucket(T)` samples (module docstring; `residual_fn` must then
      be causal in the arrays of `args` whose axis 0 has the residual's `T` entries); False
      compiles for the exact length.

    **Returns:** a `PEMResult`; `start_costs` holds the final cost from each start.
    """
    runtime.guard()
    theta0 = check_start(theta0, solver, max_steps, 0, batch)
    args, T = padded(residual_fn, theta0, args, 0, pad)
    res = _minimize_jit(residual_fn, theta0, args, true_length(T), solver, int(max_steps), float(rtol),
                        float(atol), float(learning_rate), bool(covariance), batch,
                        int(screen_steps))
    if throw and not bool(jnp.isfinite(res.cost)):
        raise FitError(f"minimize: no start point gave a finite cost ({theta0.shape[0]} tried)")
    return res


def minimize_many(residual_fn: ResidualFn, theta0: Float[Array, "M *K p"], args: Any = None, *,
                  solver: str = "lm", max_steps: int = 200, rtol: float = 1e-8,
                  atol: float = 1e-8, learning_rate: float = 1e-2, covariance: bool = True,
                  throw: bool = True, batch: str = "vmap", screen_steps: int = 0,
                  pad: bool = True) -> PEMResult:
    """`minimize` for M independent problems of the same shape, in one compiled call.

    Used for models whose outputs do not share parameters (MISO per output): a block-diagonal
    Jacobian is then never formed. `batch` applies to the problems too: `"vmap"` holds all
    M·K problems' Jacobians at once and runs each to the slowest one's step count; `"map"`
    solves them one after another in the same compiled call (the memory of one, each stopping
    at its own count: the polynomial families' default). `theta0` is `(M, p)` or `(M, K, p)`;
    every array leaf of `args` carries the problem index on axis 0 (and time on axis 1: `pad`
    as in `minimize`). The returned `PEMResult` has a leading `M` axis on every field.
    """
    runtime.guard()
    theta0 = check_start(theta0, solver, max_steps, 1, batch)
    args, T = padded(residual_fn, theta0, args, 1, pad)
    res = minimize_many_jit(residual_fn, theta0, args, solver, int(max_steps), float(rtol),
                            float(atol), float(learning_rate), bool(covariance), batch,
                            int(screen_steps), true_length(T))
    if throw and not bool(jnp.all(jnp.isfinite(res.cost))):
        bad = int(jnp.argmax(~jnp.isfinite(res.cost)))
        raise FitError(f"minimize: problem {bad}: no start point gave a finite cost "
                       f"({theta0.shape[1]} tried)")
    return res


__all__ = ["PEMResult", "minimize", "minimize_many", "SOLVERS"]
