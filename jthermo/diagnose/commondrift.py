"""One surroundings drift for every zone: the `ambient_variation` candidate where the
surroundings are not measured.

Unmeasured surroundings are one temperature that every zone sees through its loss; a zone's own
drift (the per-zone fit) is not identified, so the candidate is refitted over all zones with the
drift shared (`common_drift_fit`), and the zones' own drifts are kept for the tests of agreement
(`decide.common_drift_z`, `decide.drift_contradicted`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from . import mechanisms as M
from . import pool as PL
from .fitting import FALL_LR, fit_joint


def common_drift_fit(theta, y, sh, level, ts_free, lay, n_iter, rounds: int = 0) -> tuple:
    """The `ambient_variation` candidate refitted over all zones with *one* surroundings drift
    (unmeasured surroundings are one temperature every zone sees), from its per-zone fits
    `theta (n, P)`: each zone's loss, heater gains (and level offset where it is free), every
    zone's initial state and the common drift (knot values, started at the median of the zones'
    own) by the simulation error. The zones' models are not coupled (no exchange, no wall), so
    this is the per-zone problem with the drift shared. Per zone a drift is not identified: a
    slow zone whose loss and level trade with its gains fits its record with a drift of another
    shape, and then predicts a record whose one drift the other zones determine poorly.
    With `rounds` > 0 the fit goes on, round after round of `n_iter` iterations (the same
    compiled program), up to `rounds` more, until a round lowers its cost by no more than
    `fitting.FALL_LR` likelihood-ratio units, $T n \\log(V_{before}/V_{after})$: the first
    round is always followed by one more (one `fit_joint` call reports no cost history; from a
    converged start that round stops at once). The tests of agreement compare this fit with the
    zones' own drifts, and an unfinished common fit reads as zones that contradict it.
    Returns (θ (n, P) with the drift written mean-free per zone as `simulate_zone` reads it and
    its mean in the level offset, residuals (T, n))."""
    n, nd = lay.n, lay.n_drift
    th = np.array(theta, float)
    T = y.shape[0]
    dr = th[:, lay.sl("drift")]
    R = PL.record_size(n, lay)
    rec0 = np.zeros((1, R))
    rec0[0, :n] = th[:, lay.sl("x0")][:, 0]
    rec0[0, 2 * n:2 * n + nd] = np.median(dr - dr.mean(axis=1, keepdims=True), axis=0)
    for r in range(1, len(lay.records)):        # later pooled records: their zones' own fits
        sx, _sw, il = PL.record_entries(n, lay, r)
        rec0[0, sx] = th[:, lay.sl("x0_rec")][:, r - 1]
        rec0[0, il] = float(np.median(th[:, lay.sl("ts0_rec")][:, r - 1] - th[:, lay.sl("ts0")][:, 0])) * ts_free
    zone = ("log_a", "log_b") + (("ts0",) if ts_free else ())
    mask = np.concatenate([np.tile(lay.mask(zone), n), np.ones(n), np.zeros(n), np.ones(nd), [0.0],
                           np.zeros(R - 2 * n - nd - 1)])
    mask = PL.record_mask(mask, lay, n * lay.size, False, bool(ts_free))
    more = len(lay.records) - 1 if lay.records else 0
    fper = {"events": jnp.zeros((1, T, n)), "delay": jnp.zeros(1), "ts_level": jnp.asarray([float(level)]),
            "ts_free": jnp.asarray([float(ts_free)]), "u_pad": jnp.asarray(sh["u_pad"])[None]}
    n_act = 4 * math.ceil((n * (1 + lay.nu + int(bool(ts_free))) + n + nd + more * (n + int(bool(ts_free)))) / 4)
    on = jnp.asarray(M.on_vector(("ambient_variation",))[None])
    sse = np.inf
    for _ in range(1 + rounds):
        thj, rec, yh, _ = fit_joint(jnp.asarray(th[None]), on, jnp.asarray(rec0), jnp.asarray(mask[None]),
                                    jnp.asarray(y), jnp.ones(T), fper, sh, lay, n_iter, n_act)
        before, sse = sse, float(np.sum((y - np.asarray(yh[0])) ** 2))
        th, rec0 = np.array(thj[0]), np.array(rec)
        if not y.size * np.log(before / sse) > FALL_LR:
            break
    thj, rec = th, rec0[0]
    d = rec[2 * n:2 * n + nd]
    thj[:, lay.sl("x0")] = rec[:n, None]
    thj[:, lay.sl("drift")] = (d - d.mean())[None, :]
    if ts_free:
        thj[:, lay.sl("ts0")] += d.mean()
    else:
        thj[:, lay.sl("drift")] = d[None, :]
    for r in range(1, len(lay.records)):
        sx, _sw, il = PL.record_entries(n, lay, r)
        thj[:, lay.sl("x0_rec").start + r - 1] = rec[sx]
        if ts_free:                 # as `pool.simulate_full` sees record r's surroundings
            thj[:, lay.sl("ts0_rec").start + r - 1] = thj[:, lay.sl("ts0")][:, 0] + rec[il]
    return thj, y - np.asarray(yh[0])


__all__ = ["common_drift_fit"]
