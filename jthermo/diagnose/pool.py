"""Pooled estimation records: several records of one plant fitted as one model.

The records $r = 0 \\dots R-1$ (lengths $T_r$, their own inputs) are concatenated in time and
every simulation runs record by record: each record starts from its own initial state (zone
temperatures, the wall of a stored-heat body) with the input before it at its own mean, sees
its own surroundings level (an offset where the surroundings are not measured) and its own
drift knots (`drift_basis`: one block of hat functions per record); the physical parameters
(losses, heater gains, every mechanism's) are shared. The simulation error of all records
together is then one residual vector, so every test of the diagnosis is on the pooled
likelihood: with one noise variance per zone, $m \\log V$ over all $m = \\sum_r T_r$ samples.

Where the parameters sit: the first record's states are where a single record keeps them
(`x0`, `xw0`, `ts0`; `x0`, `w0`, level in a coupled model's record vector), the later
records' in the layout's `x0_rec`, `xw0_rec`, `ts0_rec` groups (per-zone fits) and after the
first record's entries of the record vector (coupled fits: `record_size`). A record after the
first sees the surroundings at `ts_level` plus its own fitted offset whenever the surroundings
are not measured (an "at rest" level is the first record's). One record: every function here
is the single-record one (`lay.records` is empty).
"""

from __future__ import annotations

import numpy as np
import jax.numpy as jnp
from scipy.optimize import lsq_linear
from scipy.signal import lfilter

from . import mechanisms as M

#: per-sample entries of a simulation's dict (split by record); the rest are record-wide
PER_SAMPLE = ("y", "u", "ynb", "ybar", "events", "wdev", "Phi")
#: a baseline heater gain the least squares put at its bound is stored at this share of the
#: zone's largest (its logarithm must be finite)
GAIN_FLOOR = 1e-12
#: loss rates (1/s) of the pooled baseline's grid, then refined by golden section
RATE_RANGE = (1.0 / 20000.0, 1.0)
RATE_GRID = 48


def bounds(lengths) -> list[tuple[int, int]]:
    """(start, stop) sample of each record in the concatenation."""
    c = np.concatenate([[0], np.cumsum(lengths)]).astype(int)
    return [(int(a), int(b)) for a, b in zip(c[:-1], c[1:])]


def drift_basis(lengths, ts: float) -> tuple[np.ndarray, tuple[int, ...]]:
    """Block-diagonal drift basis `(sum T_r, sum K_r)`: each record its own hat functions
    (`mechanisms.drift_basis`), zero on the other records; and the knots per record."""
    knots = tuple(M.n_drift_knots(T, ts) for T in lengths)
    Phi = np.zeros((int(sum(lengths)), int(sum(knots))))
    k = 0
    for (a, b), K in zip(bounds(lengths), knots):
        Phi[a:b, k:k + K] = M.drift_basis(b - a, ts, K)
        k += K
    return Phi, knots


def _record_theta(theta, lay, r):
    """One zone's vector `theta (P,)` as record `r` sees it (its own x0, ts0, xw0 in place)."""
    if r == 0:
        return theta
    for own, more in (("x0", "x0_rec"), ("ts0", "ts0_rec"), ("xw0", "xw0_rec")):
        theta = theta.at[lay.sl(own)].set(theta[lay.sl(more)][r - 1])
    return theta


def _split(d: dict, a: int, b: int, r: int) -> dict:
    out = {k: (v[a:b] if k in PER_SAMPLE else v) for k, v in d.items() if k != "u_pads"}
    out["u_pad"] = d["u_pads"][r]
    return out


def pooled(d: dict, lay) -> bool:
    """Whether the simulation dict `d` is of pooled records (it carries each record's `u_pads`)."""
    return bool(lay.records) and "u_pads" in d


def simulate_zone(theta, on, z, lay):
    """`mechanisms.simulate_zone` record by record (pooled `z`), concatenated `(sum T_r,)`."""
    if not pooled(z, lay):
        return M.simulate_zone(theta, on, z, lay)
    return jnp.concatenate([M.simulate_zone(_record_theta(theta, lay, r), on, _split(z, a, b, r), lay)
                            for r, (a, b) in enumerate(bounds(lay.records))])


def record_size(n: int, lay) -> int:
    """Entries of a coupled model's record vector: [x0 (n), w0 (n), drift, level] and, per
    record after the first, [x0 (n), w0 (n), level offset]."""
    return 2 * n + lay.n_drift + 1 + max(len(lay.records) - 1, 0) * (2 * n + 1)


def record_entries(n: int, lay, r: int) -> tuple[slice, slice, int]:
    """(x0, w0, level) positions of record `r` in the record vector."""
    if r == 0:
        return slice(0, n), slice(n, 2 * n), 2 * n + lay.n_drift
    a = 2 * n + lay.n_drift + 1 + (r - 1) * (2 * n + 1)
    return slice(a, a + n), slice(a + n, a + 2 * n), a + 2 * n


def simulate_full(Theta, on, f, lay, rec):
    """`mechanisms.simulate_full` record by record (pooled `f`), concatenated `(sum T_r, n)`."""
    if not pooled(f, lay):
        return M.simulate_full(Theta, on, f, lay, rec)
    n, kv = lay.n, lay.n_drift
    out = []
    lev0 = rec[2 * n + kv]
    for r, (a, b) in enumerate(bounds(lay.records)):
        sx, sw, il = record_entries(n, lay, r)
        fr = _split(f, a, b, r)
        if r:
            fr["ts_level"] = f["ts_level"] + rec[il]
        rr = jnp.concatenate([rec[sx], rec[sw], rec[2 * n:2 * n + kv], lev0[None]])
        out.append(M.simulate_full(Theta, on, fr, lay, rr))
    return jnp.concatenate(out, axis=0)


def record_start(rec0: np.ndarray, y: np.ndarray, lay, level: float, gam) -> np.ndarray:
    """`rec0 (R,)` with the later records' initial states at their first samples and their
    walls between those and `level` (as the first record's default start)."""
    n = lay.n
    rec0 = np.array(rec0, float)
    for r, (a, _b) in enumerate(bounds(lay.records)):
        if r:
            sx, sw, il = record_entries(n, lay, r)
            rec0[sx] = y[a]
            rec0[sw] = level + (y[a].mean() - level) / (1.0 + gam)
            rec0[il] = 0.0
    return rec0


def record_mask(mask: np.ndarray, lay, offset: int, walls: bool, level: bool) -> np.ndarray:
    """`mask` with the later records' entries of a record vector starting at `offset` set:
    initial states free, walls where `walls`, level offsets where `level`."""
    n = lay.n
    for r in range(1, len(lay.records)):
        sx, sw, il = record_entries(n, lay, r)
        mask[..., offset + sx.start:offset + sx.stop] = 1.0
        mask[..., offset + sw.start:offset + sw.stop] = float(walls)
        mask[..., offset + il] = float(level)
    return mask


def write_records(th: np.ndarray, rec: np.ndarray, lay) -> np.ndarray:
    """The later records' initial states and level offsets of record vectors `rec (S, R)`
    written where the per-zone models keep them (`x0_rec`, `ts0_rec`) in `th (S, n, P)`."""
    n = lay.n
    for r in range(1, len(lay.records)):
        sx, _sw, il = record_entries(n, lay, r)
        th[:, :, lay.sl("x0_rec").start + r - 1] = rec[:, sx]
        th[:, :, lay.sl("ts0_rec").start + r - 1] = rec[:, il][:, None]
    return th


# ---- the baseline of pooled records (NumPy, as `baseline.py`) ---------------------------------

def _zone_design(a, u, lengths, ts, level, ts_free):
    """Columns of one zone's first-order simulation, linear in [gains (nu), x0_r (R), T_s,r (R)
    if free] at loss rate `a`, and the part fixed by a known level."""
    ad = np.exp(-a * ts)
    g = (1.0 - ad) / a
    R = len(lengths)
    cols_u, cols_x, cols_s, fixed = [], [], [], []
    for r, (s, e) in enumerate(bounds(lengths)):
        ur = u[s:e]
        # x_k = ad^k x0 + g sum_{m<k} ad^(k-1-m) (b u_m + a T_s)
        F = lfilter([0.0, g], [1.0, -ad], ur, axis=0)
        k = np.arange(e - s)
        dec = ad ** k
        X = np.zeros((e - s, R))
        X[:, r] = dec
        S = np.zeros((e - s, R))
        S[:, r] = 1.0 - dec
        cols_u.append(F)
        cols_x.append(X)
        cols_s.append(S)
        fixed.append((1.0 - dec) * level)
    X = [np.concatenate(cols_u), np.concatenate(cols_x)] + ([np.concatenate(cols_s)] if ts_free else [])
    return np.concatenate(X, axis=1), (0.0 if ts_free else np.concatenate(fixed))


def _zone_lsq(a, y, u, lengths, ts, level, ts_free):
    X, fixed = _zone_design(a, u, lengths, ts, level, ts_free)
    nu = u.shape[1]
    lo = np.concatenate([np.zeros(nu), np.full(X.shape[1] - nu, -np.inf)])
    sol = lsq_linear(X, y - fixed, bounds=(lo, np.full(X.shape[1], np.inf)), method="bvls")
    return float(np.sum((y - fixed - X @ sol.x) ** 2)), sol.x


def fit_baseline(theta0, y, u, lengths, ts: float, level: float, ts_free: float, lay) -> np.ndarray:
    """Baseline parameters `(n, P)` of pooled records: per zone the shared loss rate and heater
    gains ($\\ge 0$), each record's initial temperature (and level offset when `ts_free`) at
    their least-squares optimum (variable projection: bounded linear least squares for the
    linear part, a log grid then golden section on the rate); the rest as in `theta0`."""
    th = np.array(theta0, float)
    u = np.where(np.asarray(u, float) > 1e-12, u, 0.0)
    nu, R = u.shape[1], len(lengths)
    grid = np.exp(np.linspace(np.log(RATE_RANGE[0]), np.log(RATE_RANGE[1]), RATE_GRID))
    for i in range(y.shape[1]):
        cost = lambda la: _zone_lsq(np.exp(la), y[:, i], u, lengths, ts, level, ts_free)[0]   # noqa: E731
        c = [cost(np.log(a)) for a in grid]
        j = int(np.argmin(c))
        lo, hi = np.log(grid[max(j - 1, 0)]), np.log(grid[min(j + 1, RATE_GRID - 1)])
        phi = (np.sqrt(5.0) - 1.0) / 2.0
        p, q = hi - phi * (hi - lo), lo + phi * (hi - lo)
        cp, cq = cost(p), cost(q)
        for _ in range(40):
            if cp < cq:
                hi, q, cq = q, p, cp
                p = hi - phi * (hi - lo)
                cp = cost(p)
            else:
                lo, p, cp = p, q, cq
                q = lo + phi * (hi - lo)
                cq = cost(q)
        la = p if cp < cq else q
        if c[j] < min(cp, cq):
            la = np.log(grid[j])
        _, x = _zone_lsq(np.exp(la), y[:, i], u, lengths, ts, level, ts_free)
        b = x[:nu]
        th[i, lay.sl("log_a")] = la
        th[i, lay.sl("log_b")] = np.log(np.maximum(b, GAIN_FLOOR * max(float(np.max(b)), 1e-300)))
        x0 = x[nu:nu + R]
        th[i, lay.sl("x0")] = x0[0]
        th[i, lay.sl("x0_rec")] = x0[1:]
        if ts_free:
            s = x[nu + R:nu + 2 * R] - level
            th[i, lay.sl("ts0")] = s[0]
            th[i, lay.sl("ts0_rec")] = s[1:]
    return th


def record_thetas(theta, lay) -> list[np.ndarray]:
    """Per-zone vectors `theta (n, P)` as each pooled record sees them (NumPy)."""
    th = np.asarray(theta, float)
    out = [th]
    for r in range(1, len(lay.records)):
        t = th.copy()
        for own, more in (("x0", "x0_rec"), ("ts0", "ts0_rec"), ("xw0", "xw0_rec")):
            t[:, lay.sl(own)] = th[:, lay.sl(more)][:, r - 1:r]
        out.append(t)
    return out


def split_rows(x, lengths) -> list:
    """`x (sum T_r, ...)` split into the records' rows."""
    return [x[a:b] for a, b in bounds(lengths)]


def evidence_shares(res_base, res_cand, lengths) -> list[dict]:
    """Each record's share of a candidate's estimation evidence: its part of the pooled sum of
    squares the candidate removes (`sse_share`, the shares add up to 1), and its own likelihood
    ratio $T_r \\sum_i \\log(V_{0,ri}/V_{1,ri})$ (per zone variances, as `decide.likelihood_ratio`
    without the whitening)."""
    b = split_rows(np.asarray(res_base, float), lengths)
    c = split_rows(np.asarray(res_cand, float), lengths)
    gain = np.array([np.sum(x ** 2) - np.sum(z ** 2) for x, z in zip(b, c)])
    tot = float(gain.sum())
    out = []
    for x, z, g in zip(b, c, gain):
        v0, v1 = np.mean(x ** 2, axis=0), np.mean(z ** 2, axis=0)
        lr = float(x.shape[0] * np.sum(np.log(np.maximum(v0, 1e-300) / np.maximum(v1, 1e-300))))
        out.append({"samples": int(x.shape[0]), "sse_share": float(g / tot) if tot > 0 else float("nan"),
                    "likelihood_ratio": round(lr, 2)})
    return out


__all__ = ["bounds", "drift_basis", "evidence_shares", "fit_baseline", "pooled", "record_size",
           "record_thetas", "simulate_full", "simulate_zone", "split_rows"]
