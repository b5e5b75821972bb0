"""The diagnosis fits: mechanism-library models of every zone and record, vmapped over problems.

`jthermo.identify.pem.minimize` compiles one solve per model structure; diagnosis fits eight
structures (and combinations) for every zone at once. Here a structure is a 0/1 mask over one
flat parameter vector plus the mechanism switches, so all candidates and zones share one
compiled solve of the masked Levenberg–Marquardt `jthermo.identify.lm.masked_lm`. The cost is
the simulation error (output error).

The coupled programs (`fit_joint`, hence `fit_records`) and `sim_zones` are compiled with
`runtime.quick_compile()` options (XLA's older CPU fusion emitters): on the latency record's
diagnosis they compile in 8.48 instead of 11.57 (first joint fit), 8.12 instead of 9.58
(validation) and 0.89 instead of 1.69 CPU s, run in the same time and give the same fits to
5e-13 (`python benchmarks/diagnose_compile_options.py`, load 6-8). The per-zone fits
(`fit_zones`) keep XLA's default options: with the older emitters they compiled in 5.88 instead
of 7.36 CPU s but ran in 6.65 instead of 5.53, and they run on every call.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..identify.lm import masked_lm
from ..runtime import quick_compile
from .mechanisms import simulate_full, simulate_zone


@functools.cache
def _compiled(fn, static: tuple, quick: bool = True):
    """`fn` jitted with `static` argument names, with `runtime.quick_compile()` options if
    `quick` (once per process: the options are probed on first use, not at import)."""
    return jax.jit(fn, static_argnames=static, compiler_options=quick_compile() if quick else None)


def _zone_residual(theta, on, z, lay):
    return z["y"] - simulate_zone(theta, on, z, lay)


def _fit_zones(theta0, mask, on, per, shared, lay, n_iter, n_active=None):
    def one(t, m, o, p):
        z = {**shared, **p}
        return masked_lm(lambda th: _zone_residual(th, o, z, lay), t, m, n_iter, n_active)

    return jax.vmap(one)(theta0, mask, on, per)


def fit_zones(theta0, mask, on, per, shared, lay, n_iter, n_active=None):
    """Fit B independent zone problems: `theta0, mask (B, P)`, `on (B, 8)`, `per` a dict of
    per-problem arrays (leading B axis: y, ynb, events, delay), `shared` a dict common to all;
    `n_active` (static) at least the largest number of free parameters of one problem."""
    return _compiled(_fit_zones, ("lay", "n_iter", "n_active"), False)(theta0, mask, on, per, shared, lay,
                                                                        n_iter, n_active)


def _sim_zones(theta, on, per, shared, lay):
    return jax.vmap(lambda t, o, p: simulate_zone(t, o, {**shared, **p}, lay))(theta, on, per)


def sim_zones(theta, on, per, shared, lay):
    """Per-zone (series-parallel) simulations of B problems, `(B, T)`."""
    return _compiled(_sim_zones, ("lay",))(theta, on, per, shared, lay)


def _fit_coupled(Theta, on, rec0, mask, y, weight, fp, f_shared, lay, n_iter, n_active):
    """Masked LM on one coupled model's vector $[\\mathrm{vec}\\,\\Theta;\\ r]$ (zone parameters,
    record parameters): residual $w_k (y_k - \\hat y_k(\\Theta, r))$, $w$ the per-sample weight."""
    f = {**f_shared, **fp}
    nP = Theta.size
    split = lambda v: (v[:nP].reshape(Theta.shape), v[nP:])

    def res(v):
        Th, r = split(v)
        return (weight[:, None] * (y - simulate_full(Th, on, f, lay, r))).reshape(-1)

    v, c, _ = masked_lm(res, jnp.concatenate([Theta.reshape(-1), rec0]), mask, n_iter, n_active)
    Th, r = split(v)
    return Th, r, simulate_full(Th, on, f, lay, r), c


def _fit_joint(Theta0, on, rec0, mask, y, weight, f_per, f_shared, lay, n_iter, n_active=None):
    return jax.vmap(lambda *a: _fit_coupled(*a[:4], y, weight, a[4], f_shared, lay, n_iter, n_active))(
        Theta0, on, rec0, mask, f_per)


def fit_joint(Theta0, on, rec0, mask, y, weight, f_per, f_shared, lay, n_iter, n_active=None):
    """Fit M coupled models jointly over all zones by simulation error (output error): the zones'
    parameters `Theta0 (M, n, P)` and the record parameters `rec0 (M, R)` (initial states, drift,
    surroundings level offset; see `simulate_full`), `mask (M, n P + R)` 1 where free, `on (M, 8)`,
    `y (T, n)`, `weight (T,)` per-sample weights (0 for padding), `f_per` per-model entries of the
    simulation's dict. Returns
    (Θ (M, n, P), rec (M, R), yhat (M, T, n), cost (M,))."""
    return _compiled(_fit_joint, ("lay", "n_iter", "n_active"))(Theta0, on, rec0, mask, y, weight, f_per,
                                                                 f_shared, lay, n_iter, n_active)


def fit_records(Theta, on, rec0, mask, y, f_per, f_shared, lay, n_iter):
    """Estimate each model's record parameters (initial states, drift) on a record by masked LM
    on the coupled simulation, then simulate it: `Theta (M, n, P)`, `on (M, 8)`,
    `rec0, mask (M, R)`; returns (rec, yhat (M, T, n), cost (M,))."""
    full = jnp.concatenate([jnp.zeros((Theta.shape[0], Theta[0].size), mask.dtype), mask], axis=1)
    _, r, yh, c = fit_joint(Theta, on, rec0, full, y, jnp.ones(y.shape[0], y.dtype), f_per, f_shared,
                            lay, n_iter, rec0.shape[1])
    return r, yh, c


__all__ = ["fit_joint", "fit_records", "fit_zones", "sim_zones"]
