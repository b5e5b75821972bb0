"""A masked Levenberg–Marquardt solver for many small least-squares problems at once.

An optimistix least-squares solver (`MaskedLM`: `init` / `step` / `terminate` /
`postprocess`, run by `optimistix.least_squares`), so it shares the loop, the results and the
stopping interface of the PEM engine's solvers (`jthermo.identify.pem`). What it adds: a
problem's structure is a 0/1 mask over one flat parameter vector, a traced array, so problems
with different sets of free parameters (model candidates, zones, records) share one compiled
solve and can be batched with `jax.vmap` (or `jax.lax.map`): masked parameters get a zero step.
Each iteration tries three damping values in parallel and keeps the best (Marquardt 1963;
Ljung 1999, §10.2). Used by the mismatch diagnosis (`jthermo.diagnose.fitting`).

The three damped systems are solved one matrix at a time (`lax.map`), their costs batched. A
batched solve calls LAPACK's LU through jaxlib's batch kernel, which above a work threshold
(2e5 flops in jaxlib's source: the diagnosis's joint fits' three 68 x 68 matrices exceed it, its
per-zone fits' 10-20 do not) deals the matrices to XLA's CPU thread pool and blocks its own
pool thread until they are done: two such programs running at once on a two-thread pool (two
cores) each held one thread and waited for good (the hang of the diagnosis's joint fits split
over two threads or devices, `gdb`: both pool threads in `ParallelBatchMap`). One matrix is
factored in the calling thread. Same results: one matrix's LU is the batch's.
"""

from __future__ import annotations

from typing import Any, Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

#: iterations over which `masked_lm(..., rtol=...)` measures the cost's fall
STALL = 3
#: the damping's start and bounds
LAMBDA0, LAMBDA_MIN, LAMBDA_MAX = 1e-2, 1e-9, 1e9


class _State(eqx.Module):
    idx: Any            # (na,) the free parameters' indices
    valid: Any          # (na,) 1 for a used Jacobian column
    tangents: Any       # (na, P) their unit tangents
    cost: Any           # the cost at y
    lam: Any            # the damping
    k: Any              # iterations done
    stop: Any           # iterations allowed (the budget)
    hist: Any           # (n_iter,) the cost after each iteration
    r: Any              # the residual at y ...
    J: Any              # ... and its Jacobian (m, na), reused after a rejected step
    moved: Any          # whether y moved in the last iteration (r, J to recompute)


def _cost(r):
    c = jnp.mean(r ** 2)
    return jnp.where(jnp.isfinite(c), c, jnp.inf)


class MaskedLM(optx.AbstractLeastSquaresSolver):
    """Levenberg–Marquardt over the parameters a mask frees (`masked_lm` for the maths).

    `options`: `mask` `(P,)` (required), `budget` (optional traced iteration count). Fields:
    `n_iter` (the history's length, the solve's `max_steps`), `n_active` (Jacobian columns),
    `rtol` (the stall rule, None: none), `geodesic` (the fourth trial). The cost is
    $\\frac1m\\|r\\|^2$; `atol` and `norm` are optimistix's interface, unused."""

    n_iter: int = eqx.field(static=True)
    n_active: int = eqx.field(static=True)
    rtol: float | None = eqx.field(static=True, default=None)
    geodesic: bool = eqx.field(static=True, default=False)
    atol: float = eqx.field(static=True, default=0.0)
    norm: Callable = eqx.field(static=True, default=optx.max_norm)

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        mask = options["mask"]
        dt, P, na = y.dtype, y.shape[0], self.n_active
        idx = jnp.nonzero(mask > 0, size=na, fill_value=0)[0]
        valid = (jnp.arange(na) < jnp.sum(mask > 0)).astype(dt)
        budget = options.get("budget")
        stop = (jnp.asarray(self.n_iter, jnp.int32) if budget is None
                else jnp.minimum(jnp.asarray(budget, jnp.int32), self.n_iter))
        r0 = fn(y, args)[0]
        c0 = _cost(r0)
        return _State(idx=idx, valid=valid, tangents=jax.nn.one_hot(idx, P, dtype=dt) * valid[:, None],
                      cost=c0, lam=jnp.asarray(LAMBDA0, dt), k=jnp.asarray(0, jnp.int32), stop=stop,
                      hist=jnp.full(self.n_iter, c0, dt), r=jnp.zeros(f_struct.shape, f_struct.dtype),
                      J=jnp.zeros(f_struct.shape + (na,), f_struct.dtype), moved=jnp.asarray(True))

    def step(self, fn, y, args, options, state, tags):
        residual = lambda th: fn(th, args)[0]      # noqa: E731

        def linear(th):
            """$r(\\theta)$ and its Jacobian `(m, na)` over the free parameters."""
            r, jvp = jax.linearize(residual, th)
            J = jax.vmap(jvp, out_axes=1)(state.tangents)
            return r, jnp.where(jnp.isfinite(J), J, 0.0)

        r, J = jax.lax.cond(state.moved, linear, lambda _: (state.r, state.J), y)
        th, c, lam, moved = _damping_round(residual, y, state, r, J, self.geodesic)
        state = eqx.tree_at(lambda s: (s.cost, s.lam, s.k, s.hist, s.r, s.J, s.moved), state,
                            (c, lam, state.k + 1, state.hist.at[state.k].set(c), r, J, moved))
        return th, state, None

    def terminate(self, fn, y, args, options, state, tags):
        done = state.k >= state.stop
        if self.rtol is not None:
            back = state.hist[jnp.maximum(state.k - 1 - STALL, 0)]      # the cost STALL iterations ago
            stalled = (state.k > STALL) & (back - state.cost <= self.rtol * jnp.abs(back))
            done = done | stalled | (state.lam >= LAMBDA_MAX)
        return done, optx.RESULTS.successful

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}


def _damping_round(residual, th, state, r, J, geodesic):
    """One damping round from $(r, J)$ at `th`: the new (θ, cost, λ) and whether it moved."""
    idx, valid, c_now, lam = state.idx, state.valid, state.cost, state.lam
    H = J.T @ J
    gvec = J.T @ r
    d = jnp.diagonal(H)
    scale = jnp.where(valid > 0, d + 1e-9 * (jnp.max(d) + 1e-30), 1.0)
    Hm = H * (valid[:, None] * valid[None, :]) + jnp.diag(1.0 - valid)

    def solve(lm):
        return -jnp.linalg.solve(Hm + lm * jnp.diag(scale), gvec * valid)

    def trial(lm, delta, accelerate=False):
        if accelerate:
            A = Hm + lm * jnp.diag(scale)
            v = jnp.where(jnp.isfinite(delta), delta * valid, 0.0)
            h = 0.1
            rpp = (2.0 / h) * ((residual(th.at[idx].add(h * v)) - r) / h - J @ v)
            acc = -jnp.linalg.solve(A, (J.T @ jnp.where(jnp.isfinite(rpp), rpp, 0.0)) * valid)
            small = 2.0 * jnp.linalg.norm(acc) <= 0.75 * jnp.linalg.norm(delta)
            delta = jnp.where(small, delta + 0.5 * acc, delta)
        delta = jnp.clip(delta, -2.0, 2.0)     # log parameters: at most e^2 per step
        delta = jnp.where(jnp.isfinite(delta), delta * valid, 0.0)
        tn = th.at[idx].add(delta)
        return tn, _cost(residual(tn))

    lams = lam * jnp.array([0.1, 1.0, 10.0], th.dtype)
    # one matrix at a time (module docstring), the trial costs batched
    tns, cs = jax.vmap(trial)(lams, jax.lax.map(solve, lams))
    if geodesic:
        tg, cg = trial(lam, solve(lam), True)
        lams = jnp.append(lams, lam)
        tns, cs = jnp.concatenate([tns, tg[None]]), jnp.append(cs, cg)
    k = jnp.argmin(cs)
    better = cs[k] < c_now
    th = jnp.where(better, tns[k], th)
    lam = jnp.where(better, jnp.clip(lams[k] * 0.5, LAMBDA_MIN, LAMBDA_MAX),
                    jnp.clip(lam * 30.0, LAMBDA_MIN, LAMBDA_MAX))
    return th, jnp.where(better, cs[k], c_now), lam, better


def masked_lm(residual, theta0, mask, n_iter, n_active=None, rtol=None, budget=None, geodesic=False):
    """Minimise $V(\\theta) = \\frac1m \\|r(\\theta)\\|^2$ over the parameters that `mask` frees
    (`MaskedLM` run by `optimistix.least_squares`).

    **Arguments:**
    - `residual`: `residual(theta) -> (m,)`, traceable by JAX (forward mode).
    - `theta0`: `(P,)` start point; masked entries (`mask == 0`) keep their value.
    - `mask`: `(P,)` 1 for a free parameter, 0 for a fixed one (a traced array: problems with
      different masks share one compiled solve, e.g. under `jax.vmap`).
    - `n_iter`: number of iterations (static; with neither `rtol` nor `budget`: all of them).
    - `n_active`: static upper bound on the number of free parameters (default P). Only the
      first `n_active` free parameters get a Jacobian column (one forward-mode tangent each):
      a problem that frees 20 of 40 parameters pays for 20.
    - `rtol`: optional early stop (static): the iterations end once the cost has fallen by less
      than `rtol` of itself over the last `STALL` iterations (or $\\lambda$ reached its bound).
    - `budget`: optional iteration count of this problem (a traced integer, at most `n_iter`;
      0 returns the start).
    - `geodesic`: (static) a fourth trial each iteration, the damping $\\lambda$ step with
      geodesic acceleration (Transtrum & Sethna 2012): $\\delta = v + a/2$,
      $a = -(J^\\top J + \\lambda D)^{-1} J^\\top r''$, $r''$ the second directional derivative
      along $v$ by a finite difference of step 0.1 (one more residual), used only where
      $2\\|a\\| \\le 0.75 \\|v\\|$. On the diagnosis's per-zone problems it follows curved valleys
      that the plain steps crawl along.

    The Jacobian is formed only where $\\theta$ moved: after a rejected step the next iteration
    reuses $r$ and $J$ (the same values it would recompute), so a rejection costs the three
    damping trials alone. Under `jax.vmap` a batched loop runs until every problem has stopped
    (stopped problems keep their values) and both branches of the reuse are computed; under
    `jax.lax.map` each problem stops and reuses on its own.

    Each iteration linearises $r$, forms $J^\\top J$ and $J^\\top r$ over the free parameters
    (non-finite Jacobian entries count as 0; the rows and columns of fixed parameters are
    replaced by the identity) and tries the three damping values $0.1\\lambda$, $\\lambda$,
    $10\\lambda$ in parallel, with Marquardt's scaling by the diagonal $D$ of $J^\\top J$ (plus
    $10^{-9}$ of its largest entry): $\\delta = -(J^\\top J + \\lambda D)^{-1} J^\\top r$, each step
    clipped to $[-2, 2]$ per parameter (log parameters: at most a factor $e^2$). The best trial
    is kept if it lowers the cost, and $\\lambda$ becomes half its damping value; otherwise
    $\\theta$ stays and $\\lambda$ grows 30-fold ($\\lambda$ starts at $10^{-2}$ and stays in
    $[10^{-9}, 10^{9}]$). A non-finite cost counts as $+\\infty$.

    **Returns:** `(theta, cost, history)`: the final parameters `(P,)`, their cost and the cost
    after each iteration `(n_iter,)` (after an early stop: the final cost repeated).
    """
    P = theta0.shape[0]
    na = P if n_active is None else min(int(n_active), P)
    solver = MaskedLM(n_iter=int(n_iter), n_active=na, rtol=rtol, geodesic=bool(geodesic))
    options = {"mask": mask} if budget is None else {"mask": mask, "budget": budget}
    sol = optx.least_squares(lambda th, _: residual(th), solver, theta0, options=options,
                             max_steps=max(int(n_iter), 1), throw=False)
    st = sol.state
    return sol.value, st.cost, jnp.where(jnp.arange(n_iter) < st.k, st.hist, st.cost)


__all__ = ["MaskedLM", "masked_lm"]
