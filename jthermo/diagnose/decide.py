"""The decision: is a candidate mechanism's improvement more than chance, and which rivals tie?

Two tests, both on *whitened* residuals (each zone's residual filtered by an AR noise model
fitted to the richer model's residual, as prediction-error methods do; Ljung 1999, §16.4),
and a mechanism is kept only if it passes both at the per-test level $\\alpha / K$
(Bonferroni over the $K$ candidates tried, so the chance of any false finding on a record
is at most `ALPHA`):

- **estimation** (likelihood ratio): $\\Lambda = \\sum_i T'\\,\\log(S_{0,i}/S_{1,i})$ with
  $S$ the whitened residual power of zone $i$ (baseline 0, candidate 1), against the
  $\\chi^2$ quantile with as many degrees of freedom as the candidate adds parameters;
- **validation** (Diebold & Mariano 1995, one-sided): the per-sample loss differential
  $d_k = \\sum_i (\\tilde e_{0,ik}^2 - \\tilde e_{1,ik}^2)/\\sigma_{1,i}^2$ on the record the model
  was *not* fitted on, its mean less the chance gain of any parameters re-estimated on that
  record (one unit each), divided by a Newey–West standard error.

The validation statistic $z$ also decides whether two candidates are within the test's
resolution (rivals: the better one does not beat the other at the one-sided 5 % level) and
gives the reported confidence; the candidates that pass are ranked by the size of their
improvement (validation MSE), not by $z$.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2, norm

#: family-wise false-alarm rate: the chance that a record with nothing missing gets a finding
ALPHA = 0.01
#: order of the AR noise model that whitens the residuals
AR_ORDER = 4
#: one-sided level at which the better of two explanations is said to beat the other
RIVAL_LEVEL = 0.05
#: the statistic of a model whose simulation diverged (finite, so that JSON stays valid)
BIG = 1e6


def ar_filter(e: np.ndarray, order: int = AR_ORDER) -> np.ndarray:
    """AR coefficients `(n, order)` of each zone's residual `e (T, n)` by least squares."""
    e = np.asarray(e, float)
    T, n = e.shape
    out = np.zeros((n, order))
    for i in range(n):
        x = e[:, i] - e[:, i].mean()
        X = np.stack([x[order - j - 1:T - j - 1] for j in range(order)], axis=1)
        if X.shape[0] > 2 * order:
            a, *_ = np.linalg.lstsq(X, x[order:], rcond=None)
            # keep the filter a whitener, not an amplifier: a root on the unit circle would
            # turn a constant offset into nothing and a drift into white noise
            if np.max(np.abs(np.roots(np.r_[1.0, -a]))) < 0.995:
                out[i] = a
    return out


def whiten(e: np.ndarray, a: np.ndarray) -> np.ndarray:
    """$\\tilde e_k = e_k - \\sum_j a_j e_{k-j}$ per zone, the first `order` samples dropped."""
    e = np.asarray(e, float)
    T = e.shape[0]
    p = a.shape[1]
    w = e[p:].copy()
    for j in range(p):
        w -= a[None, :, j] * e[p - j - 1:T - j - 1]
    return w


def _newey_west(d: np.ndarray) -> float:
    """Long-run variance of the series `d` (Bartlett weights, Newey & West 1994 bandwidth)."""
    T = d.size
    x = d - d.mean()
    L = math.floor(4.0 * (T / 100.0) ** (2.0 / 9.0))
    v = float(x @ x) / T
    for k in range(1, L + 1):
        v += 2.0 * (1.0 - k / (L + 1.0)) * float(x[k:] @ x[:-k]) / T
    return max(v, 1e-300)


def predictive_z(e0: np.ndarray, e1: np.ndarray, extra_params: float = 0.0,
                 a: np.ndarray | None = None) -> float:
    """Diebold–Mariano $z$ that residual `e1 (T, n)` predicts better than `e0`; `extra_params`
    the number of parameters model 1 re-estimates on this record beyond model 0's."""
    if not (np.all(np.isfinite(e1))):
        return -BIG
    if not np.all(np.isfinite(e0)):
        return BIG
    a = ar_filter(e1) if a is None else a
    w0, w1 = whiten(e0, a), whiten(e1, a)
    s1 = np.mean(w1 ** 2, axis=0) + 1e-300
    d = np.sum((w0 ** 2 - w1 ** 2) / s1[None, :], axis=1)
    Tw = d.size
    return float((d.mean() - extra_params / Tw) / math.sqrt(_newey_west(d) / Tw))


def likelihood_ratio(e0: np.ndarray, e1: np.ndarray) -> float:
    """$\\Lambda = \\sum_i T' \\log(S_{0,i}/S_{1,i})$ on residuals whitened by model 1's AR."""
    if not np.all(np.isfinite(e1)):
        return -BIG
    a = ar_filter(e1)
    w0, w1 = whiten(e0, a), whiten(e1, a)
    s0 = np.mean(w0 ** 2, axis=0) + 1e-300
    s1 = np.mean(w1 ** 2, axis=0) + 1e-300
    return float(w0.shape[0] * np.sum(np.log(s0 / s1)))


def rms(x) -> float:
    """Root mean square of an array (NaN if any entry is not finite)."""
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x ** 2))) if np.all(np.isfinite(x)) else float("nan")


def sensor_noise(e: np.ndarray) -> float:
    """The measurement noise's standard deviation (°C) read from residuals `e (T, n)`:
    $\\hat\\sigma = \\mathrm{rms}(\\Delta e) / \\sqrt 2$, the white part of the noise (a model
    error is smooth from one sample to the next, white noise differences at $\\sqrt 2\\,\\sigma$)."""
    return rms(np.diff(np.asarray(e, float), axis=0)) / math.sqrt(2.0)


def below_noise(effect: float, noise: float) -> bool:
    """Whether a finding's effect, the RMS change it makes to the validation prediction (°C),
    is below the sensor noise: significant on a long record, yet smaller than what one reading
    can resolve (a 0.07 °C surroundings drift on 16 zones × 3600 samples). Reported so, not
    headlined as a physical effect."""
    return bool(np.isfinite(effect) and effect < noise)


def thresholds(n_tests: int, dof: int, alpha: float = ALPHA) -> tuple[float, float]:
    """(validation $z$, estimation $\\chi^2$) critical values at the level `alpha / n_tests`."""
    level = alpha / max(n_tests, 1)
    return float(norm.isf(level)), float(chi2.isf(level, max(dof, 1)))


def chi2_log_tail(x: float, dof: int) -> float:
    """$\\log P(\\chi^2_{dof} \\ge x)$, finite for any finite `x`: the strength of a likelihood
    ratio's evidence, for ranking. SciPy's `chi2.logsf` underflows to $-\\infty$ above
    $x \\approx 1400$ (a strong mechanism's ratio on a long record is often 2000-20000), which made
    every strong candidate's evidence equal; there the upper incomplete gamma function's
    asymptotic series is used: $\\Gamma(s, t) \\approx t^{s-1} e^{-t}[1 + (s-1)/t + (s-1)(s-2)/t^2]$,
    $s = dof/2$, $t = x/2$."""
    k = max(int(dof), 1)
    v = float(chi2.logsf(x, k))
    if np.isfinite(v) or not np.isfinite(x):
        return v
    s, t = 0.5 * k, 0.5 * float(x)
    return float((s - 1.0) * math.log(t) - t + math.log1p((s - 1.0) / t + (s - 1.0) * (s - 2.0) / t ** 2)
                 - math.lgamma(s))


def p_value(z: float) -> float:
    """One-sided p-value of a validation statistic."""
    return float(norm.sf(z)) if np.isfinite(z) else (0.0 if z > 0 else 1.0)


def confidence(z_base: float, z_runner: float | None, z_runner_est: float | None = None) -> float:
    """Confidence that the named mechanism is right: the chance the improvement is not noise
    ($1 - p$ of the test against the baseline) times the chance it beats the runner-up
    ($\\Phi(z)$ of the test against it; 1 when no other candidate improved on the baseline).

    With `z_runner_est`, the same comparison on the estimation record (charged the parameters
    the top adds beyond the runner-up), $z = \\min(z_{val}, z_{est})$: one form better than
    another shows on both records. Two forms both outside the truth's (a lamp's $u^p$ and a
    $T^4$ loss for a natural-convection $h(T)$) can differ on the validation record, whose
    levels the better extrapolating one happens to match, and tie on the longer estimation
    record."""
    c = 1.0 - p_value(z_base)
    zs = [z for z in (z_runner, z_runner_est) if z is not None and np.isfinite(z)]
    if zs:
        c *= float(norm.cdf(min(zs)))
    return float(np.clip(c, 0.0, 0.999))


#: a stored-heat body whose fitted time constant is above this many estimation-record lengths is
#: not identified by the record: over it the body acts as a near-constant heat term
BODY_TAU_MAX_RECORDS = 2.0


def body_identified(tau_s: float, record_s: float) -> bool:
    """Whether a fitted stored-heat body's time constant `tau_s` (s) is one the record of
    `record_s` seconds determines (at most `BODY_TAU_MAX_RECORDS` record lengths)."""
    return bool(np.isfinite(tau_s) and tau_s <= BODY_TAU_MAX_RECORDS * record_s)


def prefer_identified(rows: list, record_s: float, tied, n_params) -> list:
    """`rows` (significant candidates, best first: dicts with `mechanism` and `parameters`) with
    a one-parameter mechanism moved ahead of a `heat_accumulation` top whose body the record does
    not identify (`body_identified`), when the two are within the test's resolution
    (`tied(row)`: the top does not beat it, `is_rival`). Of two explanations the data cannot
    separate, the one whose parameter the record determines, with fewer parameters, is named;
    the body stays its rival. `n_params(mechanism)`: parameters it adds per zone."""
    if not rows or rows[0]["mechanism"] != "heat_accumulation":
        return list(rows)
    if body_identified(rows[0]["parameters"].get("time_constant_s", float("nan")), record_s):
        return list(rows)
    alt = next((r for r in rows[1:] if n_params(r["mechanism"]) == 1 and tied(r)), None)
    if alt is None:
        return list(rows)
    return [alt] + [r for r in rows if r is not alt]


def promotable(row: dict, record_s: float) -> bool:
    """Whether `prefer_evidence` may move `row` (a candidate: `mechanism`, `parameters`) ahead of
    the top: any mechanism but a stored-heat body whose time constant a record of `record_s`
    seconds does not identify (`body_identified`). Such a body acts as a near-constant heat term
    that gains on the estimation record what `prefer_identified` sets aside (a 5 h body on a
    40 min record named over the tied loss it mimics; set on a case of development set 19)."""
    return row["mechanism"] != "heat_accumulation" or body_identified(
        row["parameters"].get("time_constant_s", float("nan")), record_s)


def prefer_evidence(rows: list, tied, dof) -> list:
    """`rows` (significant candidates, best first by validation MSE: dicts with `mechanism` and
    `estimation_lr`) with the one of strongest estimation evidence, the smallest $\\chi^2$ tail
    of its likelihood ratio with its own degrees of freedom (`dof(row)`: the parameters it adds),
    moved first among the top and the candidates tied with it (`tied(row)`: the top does not beat
    it on the validation record, `is_rival`). Where the validation record cannot separate two
    explanations its MSE does not rank them fairly: a model that re-estimates parameters on that
    record (a body's state, a drift's knots: the drift absorbs coloured noise too, and can predict
    it better than the true plant) gains there what one that does not cannot; the estimation
    record's likelihood ratio charges every parameter (as `joint.forward_select` ranks additions).
    The slow body and the surroundings drift are ordered by their own test (`order_body_drift`):
    of the two only the one ranked first can be moved. Ties keep the validation order."""
    if len(rows) < 2:
        return list(rows)
    slow = ("heat_accumulation", "ambient_variation")
    first_slow = next((r for r in rows if r["mechanism"] in slow), None)
    pool = [rows[0]] + [r for r in rows[1:] if (r["mechanism"] not in slow or r is first_slow) and tied(r)]
    ev = lambda r: chi2_log_tail(r["estimation_lr"], dof(r))
    best = min(pool, key=ev)
    return [best] + [r for r in rows if r is not best]


def common_drift_z(drifts: np.ndarray) -> float:
    """$z$ that the zones' own fitted surroundings drifts `drifts (n, K)` (knot values, one row
    per zone's fit) are one common signal: the mean pairwise correlation $\\bar r$ of the
    mean-free rows, as Fisher's $z = \\operatorname{atanh}(\\bar r)\\sqrt{K - 3}$ (0 when $K \\le 3$
    or fewer than two zones: no evidence of agreement, so `common_drift` is False and a drift is
    not named, e.g. on a multi-zone record of 10 min or less with knots every 300 s). Unmeasured
    surroundings are one temperature that every zone sees through its loss; drifts that disagree
    are a stand-in for something else."""
    d = np.asarray(drifts, float)
    n, K = d.shape
    if n < 2 or K <= 3:
        return 0.0
    x = d - d.mean(axis=1, keepdims=True)
    s = np.linalg.norm(x, axis=1)
    if np.any(s < 1e-12):
        return 0.0
    c = (x / s[:, None]) @ (x / s[:, None]).T
    r = float(np.mean(c[np.triu_indices(n, 1)]))
    return float(np.arctanh(np.clip(r, -0.999999, 0.999999)) * math.sqrt(K - 3))


def common_drift(z_common: float) -> bool:
    """Whether the zones' drifts agree (`common_drift_z` at the one-sided `RIVAL_LEVEL`)."""
    return bool(z_common >= norm.isf(RIVAL_LEVEL))


def drift_contradicted(lrs, n_knots: int) -> bool:
    """Whether some zone contradicts one common surroundings drift: its own drift (the per-zone
    fit) fits its record better than the drift shared by every zone (`commondrift.common_drift_fit`)
    beyond chance. `lrs` the zones' likelihood ratios (own against common, whitened as
    `likelihood_ratio`), each against the $\\chi^2$ quantile with the `n_knots - 1` drift shape
    parameters a zone's own drift adds (its level is free in both), at the diagnosis's level
    `ALPHA` shared by the zones (Bonferroni): rejecting the common drift withholds a significant
    candidate, a decision at the level of every other one that names or withholds. A zone that
    sees the drift too weakly to determine it contradicts nothing (where `common_drift_z`, which compares the zones' own
    drifts, finds no agreement: such a zone's own drift trades with its gains)."""
    lrs = np.asarray(lrs, float)
    if lrs.size == 0:
        return True
    crit = chi2.isf(ALPHA / lrs.size, max(int(n_knots) - 1, 1))
    return bool(not np.all(np.isfinite(lrs)) or np.any(lrs > crit))


#: a top finding whose confidence is below this is reported as uncertain: its improvement on the
#: baseline, or its lead on the runner-up, is not established at the one-sided `RIVAL_LEVEL`
#: (the same level that makes two explanations rivals)
CONFIDENT = 1.0 - RIVAL_LEVEL


def uncertain(conf: float) -> bool:
    """Whether a top finding's `confidence` is below `CONFIDENT`: the finding is then reported as
    uncertain, with every candidate it does not beat as a rival, never as a confident name."""
    return bool(conf < CONFIDENT)


def not_worse(y: np.ndarray, e_new: np.ndarray, e_ref: np.ndarray) -> bool:
    """Whether a model with validation residuals `e_new (T, n)` predicts the record `y` at least as
    well as one with `e_ref`: validation MSE not higher *and* mean fit not lower, where the fit of
    output $i$ is $100\\,(1 - \\|e_i\\| / \\|y_i - \\bar y_i\\|)$. The MSE pools the outputs, so
    a model can lower it on a wide-swinging output while it predicts a quiet one worse; such a
    model is never reported in place of `e_ref`'s."""
    if not np.all(np.isfinite(e_new)):
        return False
    y = np.asarray(y, float)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0) + 1e-300
    fit = lambda e: float(np.mean(1.0 - np.linalg.norm(e, axis=0) / den))
    return bool(np.mean(e_new ** 2) <= np.mean(e_ref ** 2) and fit(e_new) >= fit(e_ref))


def is_rival(z_top_vs_other: float) -> bool:
    """The better explanation does not beat the other at `RIVAL_LEVEL`: they are tied."""
    return bool(z_top_vs_other < norm.isf(RIVAL_LEVEL))


__all__ = ["ALPHA", "BODY_TAU_MAX_RECORDS", "CONFIDENT", "ar_filter", "below_noise", "body_identified",
           "chi2_log_tail", "common_drift", "common_drift_z", "confidence", "drift_contradicted",
           "is_rival", "likelihood_ratio", "not_worse", "p_value", "predictive_z", "prefer_evidence",
           "prefer_identified", "promotable", "rms", "sensor_noise", "thresholds", "uncertain", "whiten"]
