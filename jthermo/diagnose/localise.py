"""Localisation: where the baseline model's residuals live.

Given the simulation residuals $e = y - \\hat y$ of the baseline on a record, report which zones
carry them, in which time windows, in which frequency band, what they correlate with (inputs,
neighbouring zones' temperature differences, temperature level, slow trends, the bed's common
mode), and whether they repeat periodically (recoat events: sudden drops, found by folding the
differenced residual at every candidate period, an epoch-folding search).
"""

from __future__ import annotations

import math

import numpy as np

from .decide import ar_filter, whiten

#: periods (s) searched for periodic drops
PERIOD_RANGE = (10.0, 600.0)
#: folding statistic (in standard errors) above which a periodic drop is reported
PERIOD_THRESHOLD = 7.0


def _corr(a, b):
    a = a - a.mean()
    b = b - b.mean()
    d = np.sqrt((a @ a) * (b @ b))
    return float(a @ b / d) if d > 0 else 0.0


def _xcorr_max(e, x, max_lag):
    """Largest |normalised cross-correlation| of e(t) with x(t - k), k = 0..max_lag."""
    e = (e - e.mean()) / (e.std() + 1e-300)
    x = (x - x.mean()) / (x.std() + 1e-300)
    T = len(e)
    best, lag = 0.0, 0
    for k in range(max_lag + 1):
        c = float(e[k:] @ x[:T - k]) / T
        if abs(c) > abs(best):
            best, lag = c, k
    return best, lag


#: largest drift (samples) of a folded event over the record between neighbouring trial periods:
#: the period grid steps by `PERIOD_DRIFT * P / T` around each period P (T samples)
PERIOD_DRIFT = 2.0


def period_grid(pmin: float, pmax: float, T: int) -> np.ndarray:
    """Trial periods (samples, fractional) from `pmin` to `pmax`: each whole-sample period $P$
    and $P + j/m_P$, $m_P = \\lceil T / (P\\,\\delta)\\rceil$ ($\\delta$ = `PERIOD_DRIFT`), so that an
    event that repeats every $P^\\ast$ samples, any fraction, drifts by at most $\\delta$ samples
    over the record when folded at the nearest trial period (a record's recoat period is not a
    whole number of samples: folded at the nearest whole one its drops smear over the period)."""
    if pmax <= pmin:
        return np.array([float(pmin)])
    out = []
    for P in range(math.floor(pmin), math.ceil(pmax) + 1):
        m = max(1, math.ceil(T / (P * PERIOD_DRIFT)))
        out.append(P + np.arange(m) / m)
    g = np.concatenate(out)
    return g[(g >= pmin - 1e-9) & (g <= pmax + 1e-9)]


def _fold(x: np.ndarray, P: float):
    """Folded means `(nb,)` and counts of `x (T,)` at a period of `P` samples (any fraction):
    sample $t$ falls in phase bin $\\lfloor (t + \\tfrac12) \\bmod P \\rfloor$ (bin $j$ holds the samples
    nearest to $mP + j$: at a period just off a whole number the bins do not slip by a sample);
    only whole periods are used."""
    m = math.floor(x.size / P + 1e-9)
    t = np.arange(math.floor(m * P + 1e-9))
    b = np.floor(np.mod(t + 0.5, P) + 1e-9).astype(int)
    nb = math.ceil(P - 1e-9)
    b = np.minimum(b, nb - 1)
    cnt = np.bincount(b, minlength=nb)
    sm = np.bincount(b, weights=x[:t.size], minlength=nb)
    return sm / np.maximum(cnt, 1), cnt


def _fold_depths(s: np.ndarray, periods: np.ndarray, sd: float):
    """For each trial period (samples), the deepest folded mean of `s` over three consecutive
    phase bins in standard errors (`sd` the per-sample deviation), and its first bin: the
    `_fold` of every period at once (one `bincount`)."""
    nb = np.ceil(periods - 1e-9).astype(int)
    W = int(nb.max())
    Tn = s.size
    t = np.arange(Tn)
    used = np.floor(np.floor(Tn / periods + 1e-9) * periods + 1e-9)
    b = np.minimum(np.floor(np.mod(t[None, :] + 0.5, periods[:, None]) + 1e-9).astype(int),
                   nb[:, None] - 1)
    rows = np.arange(periods.size)[:, None]
    flat = np.where(t[None, :] < used[:, None], rows * W + b, periods.size * W)
    cnt = np.bincount(flat.ravel(), minlength=periods.size * W + 1)[:-1].reshape(-1, W)
    sm = np.bincount(flat.ravel(), weights=np.broadcast_to(s, flat.shape).ravel(),
                     minlength=periods.size * W + 1)[:-1].reshape(-1, W)
    fm = sm / np.maximum(cnt, 1)
    inv = 1.0 / np.maximum(cnt, 1)
    j = np.arange(W)[None, :]
    sh = lambda x, k: np.take_along_axis(x, (j + k) % nb[:, None], axis=1)
    z = -(fm + sh(fm, 1) + sh(fm, 2)) / (sd * np.sqrt(inv + sh(inv, 1) + sh(inv, 2)))
    z = np.where(j < nb[:, None], z, -np.inf)
    k = np.argmax(z, axis=1)
    return z[np.arange(periods.size), k], k


def _peak_centre(s: np.ndarray, P: float, sd: float, stat: float) -> tuple[float, int]:
    """The period at the centre of the folding statistic's peak around the grid's best `P`: the
    mean of the trial periods within ±3 grid steps (61 of them) whose statistic is within one
    standard error of `stat`. Folded at any period of the peak, the three-phase window holds the
    drops (the grid's first maximum sits at the peak's edge, a drift of up to `PERIOD_DRIFT`
    samples over the record); its centre is where they line up. Returns (period, first bin)."""
    step = PERIOD_DRIFT * P / s.size
    trial = P + np.linspace(-3.0 * step, 3.0 * step, 61)
    trial = trial[trial >= 3.0]
    z, _ = _fold_depths(s, trial, sd)
    Pc = float(np.mean(trial[z >= stat - 1.0]))
    _, kc = _fold_depths(s, np.array([Pc]), sd)
    return Pc, int(kc[0])


def prewhitened_differences(D: np.ndarray) -> np.ndarray:
    """The differenced residuals `D (T-1, n)` of each zone filtered by their own AR noise model
    (`decide.ar_filter`, as the tests whiten), aligned with `D` (the first samples, which the
    filter needs, set to 0). Coloured noise differenced is far from white: its slow wander folds
    into deep phase bins at every trial period, and a drop that the baseline's slow recovery
    follows is smeared over the next samples; whitened, the noise folds as independent samples
    (the statistic's standard error holds) and a drop is one spike again. A zone whose filter is
    refused (`ar_filter`: a root near the unit circle) keeps its plain differences."""
    D = np.asarray(D, float)
    a = ar_filter(D)
    p = a.shape[1]
    if D.shape[0] <= 2 * p:
        return D
    return np.vstack([np.zeros((p, D.shape[1])), whiten(D, a)])


def detect_periodic(R: np.ndarray, ts: float, *, period_range=PERIOD_RANGE) -> dict:
    """Epoch-folding search for periodic sudden drops in residuals `R (T, n)`.

    The differenced residual, prewhitened (`prewhitened_differences`) and averaged over zones, is folded at every trial period in
    `period_range` (`period_grid`: fractions of a sample included); the statistic is the deepest
    folded mean of three consecutive phases (a sweep spreads a drop over a few samples) in units
    of its standard error.
    **Returns:** dict with `period_s`, `phase` (samples, first event), `statistic`,
    `significant`, and per-zone `zone_phase` (samples) and `zone_drop_C`.
    """
    R = np.asarray(R, float)
    T, n = R.shape
    D_raw = np.diff(R, axis=0)
    D = prewhitened_differences(D_raw)
    s = D.mean(axis=1)
    sd = np.std(s) + 1e-300
    pmin = max(3.0, period_range[0] / ts)
    # a search needs four periods in the record; a given period (a one-point range: the phases
    # of a period found on another record) needs one
    known = period_range[0] == period_range[1]
    pmax = min(period_range[1] / ts, (T - 1) / (1 if known else 4))
    grid = period_grid(pmin, pmax, len(s)) if pmax >= pmin else np.zeros(0)
    best = (0.0, 0.0, 0)
    for lo in range(0, grid.size, 512):
        z, k = _fold_depths(s, grid[lo:lo + 512], sd)
        r = int(np.argmax(z))
        if z[r] > best[0]:
            best = (float(z[r]), float(grid[lo + r]), int(k[r]))
    stat, P, k = best
    if grid.size > 1 and P > 0:
        P, k = _peak_centre(s, P, sd, stat)
    out = {"statistic": stat, "significant": bool(stat > PERIOD_THRESHOLD and P > 0)}
    if P == 0:
        out.update(period_s=float("nan"), phase=0, zone_phase=[0] * n, zone_drop_C=[0.0] * n)
        return out
    nb = math.ceil(P - 1e-9)
    zone_phase, zone_drop = [], []
    for i in range(n):
        fi, _ = _fold(D[:, i], P)
        fr, _ = _fold(D_raw[:, i], P)
        # the zone's own drop lies within a quarter period after the bed's first drop
        win = [(k + j) % nb for j in range(-2, max(nb // 4, 4))]
        j = win[int(np.argmin(fi[win]))]
        zone_phase.append(int(j + 1))               # D[t] = R[t+1] - R[t]: the drop shows at t+1
        zone_drop.append(float(-(fr[j] + min(fr[(j + 1) % nb], 0) + min(fr[(j - 1) % nb], 0))))
    out.update(period_s=float(P * ts), phase=int(k + 1), zone_phase=zone_phase,
               zone_drop_C=zone_drop)
    return out


def event_matrix(T: int, period: float, zone_phase, *, offset: int = 0) -> np.ndarray:
    """Recoat flags `(T, n)`: 1.0 at each zone's drop sample, every `period` samples (any
    fraction: the drop of event $m$ of a zone with phase $\\phi$ is at sample
    $\\lceil mP + \\phi - \\tfrac32\\rceil + 1$, the sample after the nearest to $mP + \\phi - 1$, the phase
    bin it was folded into),
    the record starting `offset` samples after the one the phases refer to."""
    n = len(zone_phase)
    E = np.zeros((T, n))
    P = float(period)
    for i, ph in enumerate(zone_phase):
        m = np.arange(math.floor((offset - ph) / P) - 1, math.ceil((T + offset) / P) + 2)
        k = np.ceil(m * P + ph - 1.5 - 1e-9).astype(int) + 1 - offset
        E[k[(k >= 0) & (k < T)], i] = 1.0
    return E


def localise(R: np.ndarray, y: np.ndarray, u: np.ndarray, ts: float) -> dict:
    """Summaries of where the residuals `R (T, n)` of a model on a record `(y, u)` live."""
    R = np.asarray(R, float)
    y = np.asarray(y, float)
    u = np.asarray(u, float)
    T, n = R.shape
    ms = np.mean(R ** 2, axis=0)
    total = float(ms.sum()) + 1e-300
    # time windows: RMS in windows of ~5 % of the record
    w = max(T // 20, 1)
    wins = [(k, float(np.sqrt(np.mean(R[k:k + w] ** 2)))) for k in range(0, T - w + 1, w)]
    wins.sort(key=lambda kv: -kv[1])
    # frequency band: share of residual power in bands (periodogram of each zone)
    F = np.abs(np.fft.rfft(R - R.mean(axis=0), axis=0)) ** 2
    f = np.fft.rfftfreq(T, ts)
    bands = {"below_1_over_600s": f < 1 / 600, "1_over_600s_to_1_over_60s": (f >= 1 / 600) & (f < 1 / 60),
             "1_over_60s_to_1_over_10s": (f >= 1 / 60) & (f < 0.1), "above_1_over_10s": f >= 0.1}
    Ptot = F[1:].sum() + 1e-300
    band_share = {k: float(F[v & (f > 0)].sum() / Ptot) for k, v in bands.items()}
    # common mode: share of residual power in the zone mean
    cm = R.mean(axis=1, keepdims=True)
    common = float(n * np.mean(cm ** 2) / (np.mean(R ** 2) * 1.0 + 1e-300) / n) if n > 1 else 1.0
    # correlations
    lag_max = min(30, T // 10)
    inp = []
    for i in range(n):
        best = max((_xcorr_max(R[:, i], u[:, j], lag_max) for j in range(u.shape[1])),
                   key=lambda cl: abs(cl[0]))
        inp.append({"zone": i + 1, "corr": round(best[0], 3), "lag_s": best[1] * ts})
    nbr = []
    for i in range(n):
        diffs = [(j, _corr(R[:, i], y[:, j] - y[:, i])) for j in range(n) if j != i]
        if diffs:
            j, c = max(diffs, key=lambda jc: abs(jc[1]))
            nbr.append({"zone": i + 1, "neighbour": j + 1, "corr": round(c, 3)})
    level = [round(_corr(R[:, i], y[:, i]), 3) for i in range(n)]
    t = np.arange(T) * ts
    trend = []
    for i in range(n):
        p = np.polyfit(t, R[:, i], 2)
        fit = np.polyval(p, t)
        trend.append(float(np.mean(fit ** 2) / (ms[i] + 1e-300)))
    ac = []
    for i in range(n):
        e = R[:, i] - R[:, i].mean()
        v = e @ e + 1e-300
        ac.append([round(float(e[k:] @ e[:T - k] / v), 3) for k in (1, 5, 20, 60)])
    return {
        "zones_rms_C": [round(float(np.sqrt(m)), 4) for m in ms],
        "zone_share": [round(float(m / total), 3) for m in ms],
        "worst_windows": [{"start_s": k * ts, "end_s": (k + w) * ts, "rms_C": round(r, 4)}
                          for k, r in wins[:3]],
        "band_share": {k: round(v, 3) for k, v in band_share.items()},
        "common_mode_share": round(common, 3),
        "input_correlation": inp,
        "neighbour_difference_correlation": nbr,
        "temperature_level_correlation": level,
        "slow_trend_share": [round(v, 3) for v in trend],
        "autocorrelation_lags_1_5_20_60": ac,
    }


__all__ = ["PERIOD_DRIFT", "PERIOD_THRESHOLD", "detect_periodic", "prewhitened_differences", "event_matrix", "localise", "period_grid"]
