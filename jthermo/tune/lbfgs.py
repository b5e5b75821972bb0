"""L-BFGS with a weak-Wolfe line search as an optimistix minimiser (`WolfeLBFGS`).

A weak-Wolfe search, not optimistix's `LBFGS`, whose search only backtracks (Armijo; its search
sees no gradient at a trial point, so it cannot ask for curvature): the tuning's cost is kinked
where an actuator saturates, and this is the search the tuning has used, so its iterates stay
the same (`tests/tune/test_optimiser_lbfgs.py` checks them against a NumPy L-BFGS). It bisects
between a step too long (the Armijo condition fails or the cost is not finite) and one too short
(the slope still below $c_2 g^\\top d$), doubling while none is too long (Lewis & Overton
2013), so every step it accepts within its budget has $s^\\top y > 0$.

Direction $d = -H g$ by the two-loop recursion over the last `memory` pairs $s_k = x_{k+1} -
x_k$, $y_k = g_{k+1} - g_k$, oldest first, with $H_0 = (s^\\top y / y^\\top y) I$ from the
newest (Nocedal & Wright 2006, Alg. 7.4); a pair is kept when $s^\\top y > 10^{-12}\\,\\|s\\|
\\|y\\|$. While no pair is kept the direction $-g$ is scaled so that its unit trial step moves
no parameter by more than `first_move` (the search may then lengthen it).

One `step` is one evaluation of the cost and its gradient (the first at the start point), so a
driver that steps in Python (`tune.optimiser`) sees every accepted iterate, and one compiled
program serves the whole run; the search's bookkeeping is in the state. A non-finite cost is
read as $+\\infty$ and non-finite gradient entries as 0. The run stops when a search finds no
decrease in `max_evals` evaluations, when an accepted step lowers the cost by at most `ftol`
of $\\max(|f|, 1)$, or when the gradient's largest entry falls below `gtol`; a search out of
evaluations that has an Armijo point takes the best one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx


class _State(eqx.Module):
    started: Any        # the start point evaluated
    x: Any              # the accepted point, its cost and gradient
    f: Any
    g: Any
    d: Any              # the search direction from x, and g'd
    slope: Any
    alpha: Any          # the trial step, the bracket [lo, hi], evaluations in this search
    lo: Any
    hi: Any
    n: Any
    found: Any          # an Armijo point seen in this search, the best one
    bx: Any
    bf: Any
    bg: Any
    S: Any              # (memory, p) curvature pairs, oldest first; `count` of them valid
    Y: Any
    count: Any
    accepted: Any       # accepted iterates after the start
    evals: Any          # evaluations of the cost and gradient
    done: Any


def direction(g, S, Y, count):
    """$-H g$ by the two-loop recursion over the last `count` rows of `S`, `Y` (oldest first),
    $H_0 = (s^\\top y / y^\\top y) I$ from the newest pair ($-g$ without pairs)."""
    m = S.shape[0]
    valid = jnp.arange(m) >= m - count

    def safe(v):
        return jnp.where(v != 0, v, 1.0)

    def back(i, carry):
        q, alphas = carry
        j = m - 1 - i
        a = jnp.where(valid[j], (S[j] @ q) / safe(Y[j] @ S[j]), 0.0)
        return q - a * Y[j], alphas.at[j].set(a)

    q, alphas = jax.lax.fori_loop(0, m, back, (g, jnp.zeros(m, g.dtype)))
    q = q * jnp.where(count > 0, (S[-1] @ Y[-1]) / safe(Y[-1] @ Y[-1]), 1.0)

    def fwd(j, q):
        return q + jnp.where(valid[j], S[j] * (alphas[j] - (Y[j] @ q) / safe(Y[j] @ S[j])), 0.0)

    return -jax.lax.fori_loop(0, m, fwd, q)


class WolfeLBFGS(optx.AbstractMinimiser):
    """L-BFGS with a weak-Wolfe search (module docstring). `fn(y, args) -> (cost, aux)`, `y` a
    flat array; `rtol`, `atol`, `norm` are optimistix's interface, unused (the stops are
    `ftol`, `gtol`, `max_evals`)."""

    first_move: float = eqx.field(static=True, default=0.05)
    memory: int = eqx.field(static=True, default=10)
    c1: float = eqx.field(static=True, default=1e-4)
    c2: float = eqx.field(static=True, default=0.9)
    max_evals: int = eqx.field(static=True, default=10)
    ftol: float = eqx.field(static=True, default=1e-9)
    gtol: float = eqx.field(static=True, default=1e-8)
    rtol: float = eqx.field(static=True, default=0.0)
    atol: float = eqx.field(static=True, default=0.0)
    norm: Callable = eqx.field(static=True, default=optx.max_norm)

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        dt, p = y.dtype, y.shape[0]
        zero, inf = jnp.zeros((), dt), jnp.asarray(jnp.inf, dt)
        return _State(started=jnp.asarray(False), x=y, f=inf, g=jnp.zeros_like(y), d=jnp.zeros_like(y),
                      slope=zero, alpha=jnp.ones((), dt), lo=zero, hi=inf, n=jnp.asarray(0, jnp.int32),
                      found=jnp.asarray(False), bx=y, bf=inf, bg=jnp.zeros_like(y),
                      S=jnp.zeros((self.memory, p), dt), Y=jnp.zeros((self.memory, p), dt),
                      count=jnp.asarray(0, jnp.int32), accepted=jnp.asarray(0, jnp.int32),
                      evals=jnp.asarray(0, jnp.int32), done=jnp.asarray(False))

    def _direction(self, g, S, Y, count):
        d = direction(g, S, Y, count)
        return jnp.where(count > 0, d, d * (self.first_move / jnp.maximum(jnp.max(jnp.abs(d)), 1e-300)))

    def step(self, fn, y, args, options, state, tags):
        s = state
        xt = jnp.where(s.started, s.x + s.alpha * s.d, s.x)
        ft, gt = jax.value_and_grad(lambda v: fn(v, args)[0])(xt)
        ft = jnp.where(jnp.isfinite(ft), ft, jnp.inf)
        gt = jnp.where(jnp.isfinite(gt), gt, 0.0)
        # the search: Armijo, curvature, the best Armijo point, the next trial step
        long_ = ~jnp.isfinite(ft) | (ft > s.f + self.c1 * s.alpha * s.slope)
        wolfe = ~long_ & (gt @ s.d >= self.c2 * s.slope)
        found = s.found | ~long_
        bx, bf, bg = (jnp.where(~long_, a, b) for a, b in ((xt, s.bx), (ft, s.bf), (gt, s.bg)))
        n = s.n + 1
        out = ~wolfe & (n >= self.max_evals)
        take = s.started & (wolfe | (out & found))
        stalled = s.started & out & ~found
        lo, hi = jnp.where(long_, s.lo, s.alpha), jnp.where(long_, s.alpha, s.hi)
        alpha = jnp.where(jnp.isfinite(hi), 0.5 * (lo + hi), 2.0 * lo)
        # an accepted step: the new point, its curvature pair, the next direction
        xn, fn_, gn = (jnp.where(s.started, jnp.where(wolfe, a, b), a) for a, b in ((xt, bx), (ft, bf), (gt, bg)))
        moved = take | ~s.started
        sv, yv = xn - s.x, gn - s.g
        keep = take & (sv @ yv > 1e-12 * jnp.sqrt((sv @ sv) * (yv @ yv)))
        S = jnp.where(keep, jnp.concatenate([s.S[1:], sv[None]]), s.S)
        Y = jnp.where(keep, jnp.concatenate([s.Y[1:], yv[None]]), s.Y)
        count = jnp.where(keep, jnp.minimum(s.count + 1, self.memory), s.count)
        d = self._direction(gn, S, Y, count)
        small = take & (s.f - fn_ <= self.ftol * jnp.maximum(jnp.abs(s.f), 1.0))
        flat = moved & (jnp.max(jnp.abs(gn)) < self.gtol)
        dt = y.dtype
        state = _State(
            started=jnp.asarray(True), x=jnp.where(moved, xn, s.x), f=jnp.where(moved, fn_, s.f),
            g=jnp.where(moved, gn, s.g), d=jnp.where(moved, d, s.d),
            slope=jnp.where(moved, gn @ d, s.slope),
            alpha=jnp.where(moved, jnp.ones((), dt), alpha), lo=jnp.where(moved, jnp.zeros((), dt), lo),
            hi=jnp.where(moved, jnp.asarray(jnp.inf, dt), hi), n=jnp.where(moved, 0, n),
            found=found & ~moved, bx=bx, bf=jnp.where(moved, jnp.inf, bf), bg=bg, S=S, Y=Y, count=count,
            accepted=s.accepted + take.astype(jnp.int32), evals=s.evals + 1,
            done=stalled | small | flat | ~jnp.isfinite(jnp.where(moved, fn_, s.f)))
        return state.x, state, None

    def terminate(self, fn, y, args, options, state, tags):
        return state.done, optx.RESULTS.successful

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}


__all__ = ["WolfeLBFGS", "direction"]
