"""The estimation records as the diagnosis's fits see them: arrays, problems, the baseline.

One record or several pooled records of one plant (`pool.py`): `lengths` is () for one record,
else each record's samples; the arrays are then the records' concatenation in time, with each
record's input before it (`u_pads`) and a drift basis of one block per record.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from . import baseline, pool
from . import mechanisms as M


def fit_percent(y, yhat):
    """Simulation fit % per output: $100 (1 - \\|y - \\hat y\\| / \\|y - \\bar y\\|)$."""
    y = np.asarray(y)
    num = np.linalg.norm(y - yhat, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0) + 1e-300
    return 100.0 * (1.0 - num / den)


def ambient_column(data):
    """Index of the measured surroundings signal (`w_ambient`, `w_surroundings`...) or None."""
    for j, name in enumerate(data.signal_names):
        low = name.lower()
        if "ambient" in low or "surround" in low:
            return j
    return None


@dataclasses.dataclass(frozen=True)
class RecordArrays:
    """What every fit of a record needs (NumPy); pooled records: their concatenation in time."""
    y: np.ndarray          # (T, n) zone temperatures, °C
    ynb: np.ndarray        # (n, T, n-1) each zone's neighbours (zeros for one zone)
    ybar: np.ndarray       # (T,) the mean zone temperature
    wdev: np.ndarray       # (T,) the surroundings' deviation from the level (zeros: not measured)
    Phi: np.ndarray        # (T, K) the drift basis (pooled: one block per record)
    u: np.ndarray          # (T, nu) the inputs
    u_pad: np.ndarray      # (nu,) the input before the record: its mean
    u_pads: np.ndarray | None = None   # (R, nu) pooled records: each record's


def record_arrays(data, amb_col, level, n_knots, lengths=()) -> RecordArrays:
    """A record's `RecordArrays`: the surroundings' deviation from `level` where column `amb_col`
    measures them; pooled `lengths`: each record's input before it (`u_pads`)."""
    y = np.asarray(data.y, float)
    u = np.asarray(data.u, float)
    T, n = y.shape
    if amb_col is not None:
        wdev = np.asarray(data.w[:, amb_col], float) - level
    else:
        wdev = np.zeros(T)
    ynb = np.stack([np.delete(y, i, axis=1) if n > 1 else np.zeros((T, 1)) for i in range(n)])
    Phi = pool.drift_basis(lengths, data.ts)[0] if lengths else M.drift_basis(T, data.ts, n_knots)
    u_pads = np.stack([x.mean(axis=0) for x in pool.split_rows(u, lengths)]) if lengths else None
    return RecordArrays(y=y, ynb=ynb, ybar=y.mean(axis=1), wdev=wdev, Phi=Phi, u=u, u_pad=u.mean(axis=0),
                        u_pads=u_pads)


def problems(rec, K, events=None, delays=None):
    """The fits' per-problem inputs (the simulator's dict) for K candidates × n zones of the
    record `rec` (zone index fastest)."""
    y = rec.y
    T, n = y.shape
    ev = np.zeros((K, T, n)) if events is None else events
    dl = np.zeros(K) if delays is None else np.asarray(delays, float)
    return {
        "y": jnp.asarray(np.tile(y.T, (K, 1))),
        "ynb": jnp.asarray(np.tile(rec.ynb, (K, 1, 1))),
        "ybar": jnp.asarray(np.tile(rec.ybar, (K * n, 1))),
        "events": jnp.asarray(np.concatenate([ev[k].T for k in range(K)], axis=0)),
        "delay": jnp.asarray(np.repeat(dl, n)),
    }


def shared(rec, level, ts_free, ts, t_ref):
    """The entries of a simulation's dict common to every problem of a record."""
    out = {"u": jnp.asarray(rec.u), "ts_level": jnp.asarray(level), "ts_free": jnp.asarray(ts_free),
           "wdev": jnp.asarray(rec.wdev), "Phi": jnp.asarray(rec.Phi),
           "u_pad": jnp.asarray(rec.u_pad), "ts": jnp.asarray(float(ts)),
           "t_ref": jnp.asarray(float(t_ref))}
    if rec.u_pads is not None:
        out["u_pads"] = jnp.asarray(rec.u_pads)
    return out


def record_starts(th0, y, level, lengths, lay):
    """Starts `th0 (n, P)` with the later pooled records' initial states at their first samples
    and level offsets at the first record's."""
    th = np.array(th0, float)
    for r, (a, _b) in enumerate(pool.bounds(lengths)):
        if r:
            th[:, lay.sl("x0_rec").start + r - 1] = y[a]
            th[:, lay.sl("ts0_rec").start + r - 1] = th[:, lay.sl("ts0")][:, 0]
            th[:, lay.sl("xw0_rec").start + r - 1] = (y[a].mean() - level - th[:, lay.sl("ts0")][:, 0]) / 2.0
    return th


def fit_baseline(th0, y, u, ts, level, ts_free, lay):
    """The baseline (`baseline.fit`; pooled records: `pool.fit_baseline`)."""
    if lay.records:
        return pool.fit_baseline(th0, y, u, lay.records, ts, level, ts_free, lay)
    return baseline.fit(th0, y, u, ts, level, ts_free, lay)


def delayed_inputs(rec: RecordArrays, lay, delay: float) -> np.ndarray:
    """The record(s)' inputs `(T, nu)` after a dead time of `delay` samples (`baseline.held`),
    each pooled record with its own input before it."""
    if rec.u_pads is None:
        return baseline.held(rec.u, rec.u_pad, delay)
    return np.concatenate([baseline.held(u, up, delay) for u, up in zip(pool.split_rows(rec.u, lay.records),
                                                                       rec.u_pads)])


def simulate_baseline(thb, rec, ts, level, ts_free, lay, delay: float = 0.0):
    """The baseline's simulation `(T, n)` of the record(s) `rec` (`record_arrays`), each pooled
    record from its own initial states with its own input before it."""
    if rec.u_pads is None:
        return baseline.simulate(thb, rec.u, rec.u_pad, ts, level, ts_free, lay, delay)
    return np.concatenate([baseline.simulate(th, u, up, ts, level, ts_free, lay, delay)
                           for th, u, up in zip(pool.record_thetas(thb, lay),
                                                pool.split_rows(rec.u, lay.records), rec.u_pads)])


__all__ = ["RecordArrays", "ambient_column", "delayed_inputs", "fit_baseline", "fit_percent", "problems", "record_arrays", "record_starts",
           "shared", "simulate_baseline"]
