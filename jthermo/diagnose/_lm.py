"""A masked Levenberg–Marquardt solver for the mechanism library, vmapped over problems.

`jthermo.identify.pem.minimize` compiles one solve per model structure; diagnosis fits eight
structures (and combinations) for every zone at once. Here a structure is a 0/1 mask over one
flat parameter vector plus the mechanism switches, so all candidates and zones share one
compiled solve: masked parameters get a zero step (their rows and columns of $J^\\top J$ are
replaced by the identity). Each iteration tries three damping values in parallel and keeps the
best (Marquardt 1963; Ljung 1999, §10.2). The cost is the simulation error (output error).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from .mechanisms import simulate_full, simulate_zone


def _lm(residual, theta0, mask, n_iter, n_active=None):
    """Generic masked LM on `residual(theta) -> (m,)`; returns (theta, cost, cost history).

    Only the first `n_active` (static) parameters with `mask == 1` get a Jacobian column (one
    forward-mode tangent each): a candidate that frees 20 of 40 parameters pays for 20."""
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

    def body(carry, _):
        th, c_now, lam = carry
        r, jvp = jax.linearize(residual, th)
        J = jax.vmap(jvp, out_axes=1)(tangents)                  # (m, na)
        J = jnp.where(jnp.isfinite(J), J, 0.0)
        H = J.T @ J
        gvec = J.T @ r
        d = jnp.diagonal(H)
        scale = jnp.where(valid > 0, d + 1e-9 * (jnp.max(d) + 1e-30), 1.0)
        Hm = H * (valid[:, None] * valid[None, :]) + jnp.diag(1.0 - valid)

        def step(lm):
            delta = -jnp.linalg.solve(Hm + lm * jnp.diag(scale), gvec * valid)
            delta = jnp.clip(delta, -2.0, 2.0)     # log parameters: at most e^2 per step
            delta = jnp.where(jnp.isfinite(delta), delta * valid, 0.0)
            tn = th.at[idx].add(delta)
            return tn, cost(tn)

        lams = lam * jnp.array([0.1, 1.0, 10.0], dt)
        tns, cs = jax.vmap(step)(lams)
        k = jnp.argmin(cs)
        better = cs[k] < c_now
        th = jnp.where(better, tns[k], th)
        lam = jnp.where(better, jnp.clip(lams[k] * 0.5, 1e-9, 1e9), jnp.clip(lam * 30.0, 1e-9, 1e9))
        c_now = jnp.where(better, cs[k], c_now)
        return (th, c_now, lam), c_now

    c0 = cost(theta0)
    (th, c, _), hist = jax.lax.scan(body, (theta0, c0, jnp.asarray(1e-2, dt)), None, length=n_iter)
    return th, c, hist


def _zone_residual(theta, on, z, lay):
    return z["y"] - simulate_zone(theta, on, z, lay)


@partial(jax.jit, static_argnames=("lay", "n_iter", "n_active"))
def fit_zones(theta0, mask, on, per, shared, lay, n_iter, n_active=None):
    """Fit B independent zone problems: `theta0, mask (B, P)`, `on (B, 8)`, `per` a dict of
    per-problem arrays (leading B axis: y, ynb, events, delay), `shared` a dict common to all;
    `n_active` (static) at least the largest number of free parameters of one problem."""
    def one(t, m, o, p):
        z = {**shared, **p}
        return _lm(lambda th: _zone_residual(th, o, z, lay), t, m, n_iter, n_active)

    return jax.vmap(one)(theta0, mask, on, per)


@partial(jax.jit, static_argnames=("lay",))
def sim_zones(theta, on, per, shared, lay):
    """Per-zone (series-parallel) simulations of B problems, `(B, T)`."""
    return jax.vmap(lambda t, o, p: simulate_zone(t, o, {**shared, **p}, lay))(theta, on, per)


@partial(jax.jit, static_argnames=("lay", "n_iter"))
def fit_records(Theta, on, rec0, mask, y, f_per, f_shared, lay, n_iter):
    """Estimate each model's record parameters (initial states, drift) on a record by masked LM
    on the coupled simulation, then simulate it: `Theta (M, n, P)`, `on (M, 8)`,
    `rec0, mask (M, R)`; returns (rec, yhat (M, T, n), cost (M,))."""
    def one(Th, o, r0, m, fp):
        f = {**f_shared, **fp}
        res = lambda r: (y - simulate_full(Th, o, f, lay, r)).reshape(-1)
        r, c, _ = _lm(res, r0, m, n_iter)
        return r, simulate_full(Th, o, f, lay, r), c

    return jax.vmap(one)(Theta, on, rec0, mask, f_per)


__all__ = ["fit_records", "fit_zones", "sim_zones"]
