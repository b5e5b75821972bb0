"""The diagnosis fits: mechanism-library models of every zone and record, vmapped over problems.

`jthermo.identify.pem.minimize` compiles one solve per model structure; diagnosis fits eight
structures (and combinations) for every zone at once. Here a structure is a 0/1 mask over one
flat parameter vector plus the mechanism switches, so all candidates and zones share one
compiled solve of the masked Levenberg–Marquardt `jthermo.identify.lm.masked_lm`. The cost is
the simulation error (output error).
"""

from __future__ import annotations

from functools import partial

import jax

from ..identify.lm import masked_lm
from .mechanisms import simulate_full, simulate_zone


def _zone_residual(theta, on, z, lay):
    return z["y"] - simulate_zone(theta, on, z, lay)


@partial(jax.jit, static_argnames=("lay", "n_iter", "n_active"))
def fit_zones(theta0, mask, on, per, shared, lay, n_iter, n_active=None):
    """Fit B independent zone problems: `theta0, mask (B, P)`, `on (B, 8)`, `per` a dict of
    per-problem arrays (leading B axis: y, ynb, events, delay), `shared` a dict common to all;
    `n_active` (static) at least the largest number of free parameters of one problem."""
    def one(t, m, o, p):
        z = {**shared, **p}
        return masked_lm(lambda th: _zone_residual(th, o, z, lay), t, m, n_iter, n_active)

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
        r, c, _ = masked_lm(res, r0, m, n_iter)
        return r, simulate_full(Th, o, f, lay, r), c

    return jax.vmap(one)(Theta, on, rec0, mask, f_per)


__all__ = ["fit_records", "fit_zones", "sim_zones"]
