"""Matrix-free Levenberg–Marquardt: PEM solves whose Jacobian does not fit in memory.

The step $\\delta = -(J^\\top J + \\lambda I)^{-1} J^\\top \\varepsilon$ is solved by conjugate
gradients (lineax `CG`), each product $J^\\top J v$ one forward (`jax.linearize`) and one reverse
(`jax.linear_transpose`) pass: memory is that of a few residual evaluations, never of $J$
(the state space at N = 16, `jthermo.identify.statespace`). The iteration is an optimistix
least-squares solver (`MatrixFreeLM`, run by `optimistix.least_squares`), as the PEM engine's
(`jthermo.identify.pem`) and the diagnosis's (`jthermo.identify.lm`) are.
"""

from __future__ import annotations

from typing import Any, Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array, Float

from .. import runtime
from ..errors import FitError
from .marquardt import LAMBDA0, next_damping
from .padding import masked_residual, padded, true_count, true_length
from .pem import EXPECTED_IMPROVEMENT_TOL, PEMResult, ResidualFn, check_start

#: the least damping of a taken step (`marquardt.next_damping`)
LAMBDA_FLOOR = 1e-9
#: a taken step that lowers the cost by less than this fraction ends the solve
STALL_RTOL = 1e-10


def _column_norms(f, theta, chunk: int = 32):
    """Column norms of the Jacobian of `f` at `theta`, `chunk` forward tangents at a time (the
    memory of `chunk` residual vectors, never the whole Jacobian)."""
    p = theta.shape[0]
    n_chunks = -(-p // chunk)
    eye = jnp.eye(n_chunks * chunk, p, dtype=theta.dtype).reshape(n_chunks, chunk, p)

    def norms(tangents):
        cols = jax.vmap(lambda v: jax.jvp(f, (theta,), (v,))[1])(tangents)
        return jnp.sqrt(jnp.sum(cols ** 2, axis=1))

    return jax.lax.map(norms, eye).reshape(-1)[:p]


def _sum_squares(r):
    c = jnp.sum(r ** 2)
    return jnp.where(jnp.isfinite(c), c, jnp.inf)


def gauss_newton_step(f, phi, lam, cg_steps: int):
    """$\\delta = -(J^\\top J + \\lambda I)^{-1} J^\\top r$ at `phi` by CG, and $g = J^\\top r$."""
    r, jvp = jax.linearize(f, phi)
    vjp = jax.linear_transpose(jvp, phi)
    g = vjp(r)[0]
    spec = jax.ShapeDtypeStruct(phi.shape, phi.dtype)
    op = lx.FunctionLinearOperator(lambda v: vjp(jvp(v))[0] + lam * v, spec,
                                   tags=lx.positive_semidefinite_tag)
    sol = lx.linear_solve(op, -g, lx.CG(rtol=1e-6, atol=1e-14, max_steps=cg_steps), throw=False)
    return jnp.where(jnp.isfinite(sol.value), sol.value, 0.0), g


class _State(eqx.Module):
    cost: Any       # $\\|r\\|^2$ at y
    lam: Any        # the damping
    done: Any       # stalled, damping unbounded, or no finite start


class MatrixFreeLM(optx.AbstractLeastSquaresSolver):
    """Levenberg–Marquardt with the CG step of `gauss_newton_step` on the cost $\\|r\\|^2$: a step
    is taken when it lowers the cost ($\\lambda / 3$), otherwise $\\lambda \\times 4$ (Marquardt's
    rule, `marquardt.next_damping`, which the NumPy polynomial solver runs too); the solve
    ends when a taken step lowers the cost by less than `STALL_RTOL` of itself or $\\lambda$
    exceeds $10^9$ (and at `max_steps`). `atol` and `norm` are optimistix's interface, unused."""

    cg_steps: int = eqx.field(static=True)
    rtol: float = eqx.field(static=True, default=STALL_RTOL)
    atol: float = eqx.field(static=True, default=0.0)
    norm: Callable = eqx.field(static=True, default=optx.max_norm)

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        c0 = _sum_squares(fn(y, args)[0])
        return _State(cost=c0, lam=jnp.asarray(LAMBDA0, y.dtype), done=~jnp.isfinite(c0))

    def step(self, fn, y, args, options, state, tags):
        f = lambda phi: fn(phi, args)[0]        # noqa: E731
        delta, _ = gauss_newton_step(f, y, state.lam, self.cg_steps)
        new = y + delta
        c_new = _sum_squares(f(new))
        better = c_new < state.cost
        rel = (state.cost - c_new) / jnp.maximum(state.cost, jnp.finfo(y.dtype).tiny)
        lam = next_damping(state.lam, better, LAMBDA_FLOOR, jnp)
        state = _State(cost=jnp.minimum(c_new, state.cost), lam=lam,
                       done=(better & (rel < self.rtol)) | (lam > 1e9))
        return jnp.where(better, new, y), state, None

    def terminate(self, fn, y, args, options, state, tags):
        return state.done, optx.RESULTS.successful

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}


def _solve(residual_fn, theta0, args, n_valid, max_steps: int, cg_steps: int):
    """The Jacobi-scaled solve from `theta0`; the first `n_valid` residual rows count."""

    def f0(th):
        r2 = masked_residual(residual_fn, th, args, n_valid)
        return jnp.reshape(r2, (-1,)) / jnp.sqrt(true_count(r2, n_valid))

    # Jacobi scaling at the start (as `pem.minimize`): unit column norms, bounded to a 1e4 range
    d = _column_norms(f0, theta0)
    d = jnp.where(jnp.isfinite(d) & (d > 0), d, 1.0)
    d = jnp.maximum(d, 1e-4 * jnp.max(d))
    f = lambda phi: f0(phi / d)                 # noqa: E731
    sol = optx.least_squares(lambda phi, _: f(phi), MatrixFreeLM(cg_steps=cg_steps), theta0 * d,
                             max_steps=max_steps, throw=False)
    phi, c = sol.value, sol.state.cost
    # honest convergence: the (almost) undamped Gauss–Newton step from the result would lower
    # the cost by less than EXPECTED_IMPROVEMENT_TOL (`pem.minimize`'s rule), relative to the
    # start's cost where the residual vanishes
    delta, g = gauss_newton_step(f, phi, 1e-9, cg_steps)
    c0 = _sum_squares(f(theta0 * d))
    improvement = -(g @ delta) / jnp.maximum(c, 1e-16 * c0 + jnp.finfo(phi.dtype).tiny)
    return phi / d, c, sol.stats["num_steps"], improvement


_solve_jit = eqx.filter_jit(_solve)


def minimize_matrix_free(residual_fn: ResidualFn, theta0: Float[Array, " p"], args: Any = None, *,
                         max_steps: int = 30, cg_steps: int = 40, pad: bool = True) -> PEMResult:
    """`pem.minimize` for problems whose `(T·ny, p)` Jacobian does not fit in memory
    (`MatrixFreeLM`, CG at most `cg_steps` iterations a step, at most `max_steps` steps).
    `converged` is honest: the undamped Gauss–Newton step from the result would lower the cost
    by less than `EXPECTED_IMPROVEMENT_TOL` (MATLAB pem's rule, as in `pem.minimize`), whatever
    the step cap. One start point `(p,)`; no covariance (NaN: it needs $(J^\\top J)^{-1}$).
    Raises `FitError` when the start or the result has no finite cost. `pad` as in
    `pem.minimize`."""
    runtime.guard()
    theta0 = check_start(theta0, "lm", max_steps, 0)
    args, T = padded(residual_fn, theta0, args, 0, pad)
    th, c, k, improvement = _solve_jit(residual_fn, theta0[0], args, true_length(T), int(max_steps), int(cg_steps))
    if not (bool(jnp.isfinite(c)) and bool(jnp.all(jnp.isfinite(th)))):
        raise FitError("minimize_matrix_free: the start point has no finite cost")
    p = th.shape[0]
    nan = jnp.asarray(jnp.nan, th.dtype)
    return PEMResult(theta=th, cost=c, converged=improvement < EXPECTED_IMPROVEMENT_TOL,
                     n_steps=k, start_costs=c[None], covariance=jnp.full((p, p), nan),
                     std=jnp.full((p,), nan), best_start=jnp.asarray(0), start_steps=k[None],
                     expected_improvement=improvement)


__all__ = ["MatrixFreeLM", "minimize_matrix_free"]
