"""A masked Levenberg–Marquardt solver for many small least-squares problems at once.

`jthermo.identify.pem.minimize` (optimistix) compiles one solve per problem structure. Here a
structure is a 0/1 mask over one flat parameter vector, so problems with different sets of free
parameters (model candidates, zones, records) share one compiled solve and can be batched with
`jax.vmap` (or `jax.lax.map`): masked parameters get a zero step. Each iteration tries three
damping values in parallel and keeps the best (Marquardt 1963; Ljung 1999, §10.2). Used by the
mismatch diagnosis (`jthermo.diagnose.fitting`).

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

import jax
import jax.numpy as jnp

#: iterations over which `masked_lm(..., rtol=...)` measures the cost's fall
STALL = 3


def masked_lm(residual, theta0, mask, n_iter, n_active=None, rtol=None, budget=None, geodesic=False):
    """Minimise $V(\\theta) = \\frac1m \\|r(\\theta)\\|^2$ over the parameters that `mask` frees.

    **Arguments:**
    - `residual`: `residual(theta) -> (m,)`, traceable by JAX (forward mode).
    - `theta0`: `(P,)` start point; masked entries (`mask == 0`) keep their value.
    - `mask`: `(P,)` 1 for a free parameter, 0 for a fixed one (a traced array: problems with
      different masks share one compiled solve, e.g. under `jax.vmap`).
    - `n_iter`: number of iterations (static; with neither `rtol` nor `budget`: no early exit,
      the loop is a `lax.scan`).
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

    With `rtol` or `budget` the loop is a `lax.while_loop` that forms the Jacobian only where
    $\\theta$ moved: after a rejected step the next iteration reuses $r$ and $J$ (the same
    values it would recompute), so the iterates are those of the fixed loop and a rejection
    costs the three damping trials alone. Under `jax.vmap` a batched loop runs until every
    problem has stopped (stopped problems keep their values) and both branches of the reuse
    are computed; under `jax.lax.map` each problem stops and reuses on its own.

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
    dt = theta0.dtype
    P = theta0.shape[0]
    na = P if n_active is None else min(int(n_active), P)
    idx = jnp.nonzero(mask > 0, size=na, fill_value=0)[0]
    valid = (jnp.arange(na) < jnp.sum(mask > 0)).astype(dt)
    tangents = jax.nn.one_hot(idx, P, dtype=dt) * valid[:, None]

    def cost(th):
        r = residual(th)
        c = jnp.mean(r ** 2)
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    def linear(th):
        """$r(\\theta)$ and its Jacobian `(m, na)` over the free parameters."""
        r, jvp = jax.linearize(residual, th)
        J = jax.vmap(jvp, out_axes=1)(tangents)
        return r, jnp.where(jnp.isfinite(J), J, 0.0)

    def update(th, c_now, lam, r, J):
        """One damping round from $(r, J)$ at `th`: the new (θ, cost, λ) and whether it moved."""
        H = J.T @ J
        gvec = J.T @ r
        d = jnp.diagonal(H)
        scale = jnp.where(valid > 0, d + 1e-9 * (jnp.max(d) + 1e-30), 1.0)
        Hm = H * (valid[:, None] * valid[None, :]) + jnp.diag(1.0 - valid)

        def solve(lm):
            return -jnp.linalg.solve(Hm + lm * jnp.diag(scale), gvec * valid)

        def step(lm, delta, accelerate=False):
            A = Hm + lm * jnp.diag(scale)
            if accelerate:
                v = jnp.where(jnp.isfinite(delta), delta * valid, 0.0)
                h = 0.1
                rpp = (2.0 / h) * ((residual(th.at[idx].add(h * v)) - r) / h - J @ v)
                acc = -jnp.linalg.solve(A, (J.T @ jnp.where(jnp.isfinite(rpp), rpp, 0.0)) * valid)
                small = 2.0 * jnp.linalg.norm(acc) <= 0.75 * jnp.linalg.norm(delta)
                delta = jnp.where(small, delta + 0.5 * acc, delta)
            delta = jnp.clip(delta, -2.0, 2.0)     # log parameters: at most e^2 per step
            delta = jnp.where(jnp.isfinite(delta), delta * valid, 0.0)
            tn = th.at[idx].add(delta)
            return tn, cost(tn)

        lams = lam * jnp.array([0.1, 1.0, 10.0], dt)
        # one matrix at a time (module docstring), the trial costs batched
        tns, cs = jax.vmap(step)(lams, jax.lax.map(solve, lams))
        if geodesic:
            tg, cg = step(lam, solve(lam), True)
            lams = jnp.append(lams, lam)
            tns, cs = jnp.concatenate([tns, tg[None]]), jnp.append(cs, cg)
        k = jnp.argmin(cs)
        better = cs[k] < c_now
        th = jnp.where(better, tns[k], th)
        lam = jnp.where(better, jnp.clip(lams[k] * 0.5, 1e-9, 1e9), jnp.clip(lam * 30.0, 1e-9, 1e9))
        return th, jnp.where(better, cs[k], c_now), lam, better

    c0 = cost(theta0)
    lam0 = jnp.asarray(1e-2, dt)
    if rtol is None and budget is None:
        def body(carry, _):
            th, c_now, lam = carry
            th, c_now, lam, _ = update(th, c_now, lam, *linear(th))
            return (th, c_now, lam), c_now

        (th, c, _), hist = jax.lax.scan(body, (theta0, c0, lam0), None, length=n_iter)
        return th, c, hist

    stop = n_iter if budget is None else jnp.minimum(jnp.asarray(budget, jnp.int32), n_iter)

    def more(carry):
        _, c, lam, k, hist, _, _, _ = carry
        if rtol is None:
            return k < stop
        back = hist[jnp.maximum(k - 1 - STALL, 0)]             # the cost STALL iterations ago
        stalled = (k > STALL) & (back - c <= rtol * jnp.abs(back))
        return (k < stop) & ~stalled & (lam < 1e9)

    def step(carry):
        th, c, lam, k, hist, r, J, moved = carry
        r, J = jax.lax.cond(moved, linear, lambda _: (r, J), th)
        th, c, lam, moved = update(th, c, lam, r, J)
        return th, c, lam, k + 1, hist.at[k].set(c), r, J, moved

    r0 = jax.eval_shape(residual, theta0)
    carry = (theta0, c0, lam0, jnp.asarray(0, jnp.int32), jnp.full(n_iter, c0, dt),
             jnp.zeros(r0.shape, r0.dtype), jnp.zeros(r0.shape + (na,), r0.dtype), jnp.asarray(True))
    th, c, _, k, hist, _, _, _ = jax.lax.while_loop(more, step, carry)
    return th, c, jnp.where(jnp.arange(n_iter) < k, hist, c)


__all__ = ["masked_lm"]
