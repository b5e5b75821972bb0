"""Recoat drops at irregular times: sudden common drops in the residuals, no period assumed.

A recoat spreads cold powder over the bed once per layer; the layers' spacing follows the
part's cross-section, so the drops need not come at a fixed period (`localise.detect_periodic`
finds them only when they do). A drop is a step down of a zone's temperature that the baseline
(a first-order response to the heaters) cannot follow: one large negative value of the
residual's first difference $D_{i,t} = R_{i,t+1} - R_{i,t}$, at (nearly) the same time in every
zone (a recoater passes the zones within a few seconds, `SWEEP_S`).

Each zone's difference is standardised robustly, $z_{i,t} = (D_{i,t} - \\mathrm{med})/(1.4826\\,
\\mathrm{MAD})$ (the drops are a few samples of many: they hardly move the median or the MAD),
and the record's drop statistic at $t$ is $G_t = \\sum_i \\min_{|j| \\le h} z_{i,t+j}$ (each
zone's deepest difference within the sweep window, $h$ = `SWEEP_S` / 2 in samples; $h = 0$
for one zone). An event is a local minimum of $G$ beyond both

- the level that iid Gaussian $z$ of the same length, zones and window reach with probability
  `ALPHA_EVENT` per record (a Gumbel fit to the minima of `N_NULL` simulated records, fixed seed),
- and the largest *rise* of the same record, $\\max_t \\sum_i \\max_{|j| \\le h} z_{i,t+j}$: a
  recoat only cools, while the spikes a misfit of the baseline leaves at the heaters' switches
  (a dead time, a lag) and heavy-tailed noise go both ways, so a drop has to stand out from the
  rises of its own record;

and the events are a recoat candidate only if there are at least `MIN_EVENTS` of them. Each
zone's flag sits at its own deepest difference within the window (the sample before the drop
shows, as `mechanisms.simulate_zone` reads a flag). The same detection runs on the validation
record's own residuals (the baseline simulated on it); there the flags are charged as
parameters re-estimated on that record (`n_flags`).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.ndimage import maximum_filter1d, minimum_filter1d

#: the time (s) within which a recoater passes every zone: a drop's zones may differ by this much
SWEEP_S = 10.0
#: chance per record that pure noise gives an event
ALPHA_EVENT = 0.01
#: simulated null records behind the Gaussian level
N_NULL = 200
#: fewest events that make a recoat candidate (one or two drops are a door, not a process)
MIN_EVENTS = 3


def _robust_z(D: np.ndarray) -> np.ndarray:
    med = np.median(D, axis=0)
    mad = 1.4826 * np.median(np.abs(D - med), axis=0)
    return (D - med) / np.maximum(mad, 1e-12)


def _window(T: int, n: int, ts: float) -> int:
    """Half-width h (samples) of the sweep window: 0 for one zone."""
    return 0 if n == 1 else min(math.ceil(0.5 * SWEEP_S / ts), max(T // 20, 1))


def _stat(z: np.ndarray, h: int, lowest: bool = True) -> np.ndarray:
    f = minimum_filter1d if lowest else maximum_filter1d
    return (f(z, 2 * h + 1, axis=0, mode="nearest") if h else z).sum(axis=1)


@functools.lru_cache(maxsize=64)
def gaussian_level(T: int, n: int, h: int, alpha: float = ALPHA_EVENT, n_null: int = N_NULL) -> float:
    """The (negative) level of $G$ that iid N(0,1) records of `T` samples and `n` zones go below
    with probability `alpha`: a Gumbel (minimum) fit by moments to `n_null` simulated minima
    (fixed seed: kept per shape, so a record the same size as an earlier one reuses it)."""
    rng = np.random.default_rng(20261127)
    mins = np.array([_stat(rng.standard_normal((T, n)), h).min() for _ in range(n_null)])
    beta = mins.std() * math.sqrt(6.0) / math.pi
    mu = mins.mean() + 0.5772156649 * beta
    # P(min < q) = 1 - exp(-exp((q - mu) / beta)) = alpha
    return float(mu + beta * math.log(-math.log(1.0 - alpha)))


def detect_drops(R: np.ndarray, ts: float, min_events: int = MIN_EVENTS) -> dict:
    """Sudden common drops in residuals `R (T, n)` at any times (see the module's text);
    `min_events` the fewest that count (on a validation record, where the estimation record has
    shown the drops, one: a short record may hold one or two layers).

    **Returns:** dict with `significant`, `flags` (per zone, the samples of its events' flags),
    `times_s` (each event's time, s, its deepest zone's drop), `statistic` (the deepest event's
    $-G$), `level` (the level it had to pass), `rise` (the record's largest rise statistic),
    `zone_drop_C` (each zone's mean drop at its flags) and `n_flags` (all zones' flags).
    """
    R = np.asarray(R, float)
    T, n = R.shape
    out = {"significant": False, "flags": [[] for _ in range(n)], "times_s": [], "statistic": 0.0,
           "level": float("nan"), "rise": float("nan"), "zone_drop_C": [0.0] * n, "n_flags": 0}
    if T < 8:
        return out
    D = np.diff(R, axis=0)
    z = _robust_z(D)
    h = _window(T - 1, n, ts)
    G = _stat(z, h)
    rise = float(_stat(z, h, lowest=False).max())
    level = max(-gaussian_level(T - 1, n, h), rise)
    out.update(statistic=float(-G.min()), level=level, rise=rise)
    gap = 2 * h + 1
    taken = np.zeros(T - 1, bool)
    events = []
    for t in np.argsort(G):
        if G[t] >= -level:
            break
        if taken[max(t - gap + 1, 0):t + gap].any():
            continue
        taken[t] = True
        events.append(int(t))
    events.sort()
    if len(events) < max(min_events, 1):
        return out
    flags = []
    for i in range(n):
        flags.append([int(max(t - h, 0) + np.argmin(z[max(t - h, 0):t + h + 1, i])) for t in events])
    times = [min(flags[i][e] for i in range(n)) * ts for e in range(len(events))]
    drops = [float(-np.mean(D[flags[i], i])) for i in range(n)]
    out.update(significant=True, flags=flags, times_s=times, zone_drop_C=drops,
               n_flags=int(sum(len(f) for f in flags)))
    return out


def flag_matrix(T: int, flags) -> np.ndarray:
    """Recoat flags `(T, n)` from each zone's flag samples (as `mechanisms.simulate_zone` reads
    them: a flag at $k$ lowers $y_{k+1}$)."""
    E = np.zeros((T, len(flags)))
    for i, f in enumerate(flags):
        f = np.asarray(f, int)
        E[f[(f >= 0) & (f < T)], i] = 1.0
    return E


def step_gain(R: np.ndarray, E: np.ndarray, a: np.ndarray, ts: float) -> float:
    """How much of the residuals `R (T, n)` the flags `E (T, n)` explain: each zone's drops as
    steps that recover at its baseline loss rate `a (n,)` (1/s), one size $\\delta_i \\ge 0$ per
    zone by least squares; the summed reduction of squared residuals (a cheap stand-in for the
    candidate's fit, to choose between two sets of flags)."""
    from scipy.signal import lfilter

    R = np.asarray(R, float)
    gain = 0.0
    for i in range(R.shape[1]):
        phi = math.exp(-float(a[i]) * ts)
        x = -lfilter([0.0, 1.0], [1.0, -phi], E[:, i])       # a flag at k lowers k+1 on
        x = x - x.mean()
        r = R[:, i] - R[:, i].mean()
        xx = float(x @ x)
        if xx > 0:
            d = max(float(x @ r) / xx, 0.0)
            gain += d * d * xx
    return gain


__all__ = ["ALPHA_EVENT", "MIN_EVENTS", "SWEEP_S", "detect_drops", "flag_matrix", "gaussian_level",
           "step_gain"]
