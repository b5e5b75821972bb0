"""A masked Levenberg–Marquardt solver for the mechanism library, vmapped over candidates.

`jthermo.identify.pem.minimize` fits one structure per compiled function; diagnosis needs eight
structures (and their combinations) at once. Here a structure is a 0/1 mask over one flat
parameter vector plus the mechanism switches, so all candidates share one compiled solve:
masked parameters get a zero step (their rows/columns of $J^\\top J$ are replaced by the
identity). Each iteration tries three damping values in parallel and keeps the best
(Marquardt 1963; Ljung 1999, §10.2).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from .mechanisms import simulate


def _residual(theta, on, args, lay):
    return (args["y"] - simulate(theta, on, args, lay)).reshape(-1)


def _cost(theta, on, args, lay):
    r = _residual(theta, on, args, lay)
    return jnp.mean(r ** 2)


def _lm_one(theta0, mask, on, args, lay, n_iter):
    dt = theta0.dtype

    def lin(th):
        r, jvp = jax.linearize(lambda t: _residual(t, on, args, lay), th)
        J = jax.vmap(jvp, out_axes=1)(jnp.eye(th.shape[0], dtype=dt) * mask[:, None])
        return r, J

    def body(carry, _):
        th, cost, lam = carry
        r, J = lin(th)
        H = J.T @ J
        gvec = J.T @ r
        d = jnp.diagonal(H)
        scale = jnp.where(mask > 0, d + 1e-9 * (jnp.max(d) + 1e-30), 1.0)
        Hm = H * (mask[:, None] * mask[None, :]) + jnp.diag(1.0 - mask)

        def step(l):
            delta = -jnp.linalg.solve(Hm + l * jnp.diag(scale), gvec * mask)
            delta = jnp.clip(delta, -2.0, 2.0)    # log parameters: at most a factor e^2 a step
            tn = th + delta * mask
            c = _cost(tn, on, args, lay)
            return tn, jnp.where(jnp.isfinite(c), c, jnp.inf)

        lams = lam * jnp.array([0.1, 1.0, 10.0], dt)
        tns, cs = jax.vmap(step)(lams)
        k = jnp.argmin(cs)
        better = cs[k] < cost
        th = jnp.where(better, tns[k], th)
        lam_new = jnp.where(better, jnp.maximum(lams[k] * 0.5, 1e-9), lam * 30.0)
        cost = jnp.where(better, cs[k], cost)
        return (th, cost, lam_new), cost

    c0 = _cost(theta0, on, args, lay)
    c0 = jnp.where(jnp.isfinite(c0), c0, jnp.inf)
    (th, cost, _), hist = jax.lax.scan(body, (theta0, c0, jnp.asarray(1e-2, dt)), None,
                                       length=n_iter)
    return th, cost, hist


@partial(jax.jit, static_argnames=("lay", "n_iter"))
def lm_batch(theta0, mask, on, args, lay, n_iter):
    """Fit K candidates at once: `theta0, mask (K, P)`, `on (K, 8)`; `args` shared except
    `delay` and `events`, which may carry a leading K axis (`args_axes`)."""
    axes = {k: (0 if k in ("delay",) else None) for k in args}
    return jax.vmap(lambda t, m, o, a: _lm_one(t, m, o, a, lay, n_iter),
                    in_axes=(0, 0, 0, axes))(theta0, mask, on, args)


@partial(jax.jit, static_argnames=("lay",))
def simulate_batch(theta, on, args, lay):
    axes = {k: (0 if k in ("delay",) else None) for k in args}
    return jax.vmap(lambda t, o, a: simulate(t, o, a, lay), in_axes=(0, 0, axes))(theta, on, args)


__all__ = ["lm_batch", "simulate_batch"]
