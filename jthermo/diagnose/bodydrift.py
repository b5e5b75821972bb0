"""A slow stored-heat body or an unmeasured surroundings drift: the test that separates them,
and how they are ordered and charged when it does not.

Both explain a slow component of the zones' misfit; only the body's follows the heaters
(`input_dependence`: the drift the drift model fits, against the input-driven temperature
through a lag, referred to circular shifts of the drive). Where that test cannot decide, the
order of the two follows parsimony (`prefer_fewer_slow`, `prefer_input_driven`) and the one named
keeps the other as its rival (`body_drift_tied`, `slow_rival`) with the test's own confidence
(`slow_order_confidence`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.stats import norm

from .decide import RIVAL_LEVEL, is_rival

#: time constants (s) of a stored-heat body tried by `input_dependence` (Bonferroni over them)
BODY_TAUS = (600.0, 1200.0, 2400.0, 4800.0)


def lag_filter(x: np.ndarray, ts: float, tau: float) -> np.ndarray:
    """Unit-gain first-order lag of `x (T,)` from a zero state, exact for a held input:
    $z_k = \\phi z_{k-1} + (1 - \\phi) x_{k-1}$, $\\phi = e^{-t_s/\\tau}$."""
    from scipy.signal import lfilter

    phi = math.exp(-ts / tau)
    return lfilter([0.0, 1.0 - phi], [1.0, -phi], np.asarray(x, float))


#: circular shifts of the drive that make the reference distribution of `input_dependence`
N_SHIFTS = 39


def _lag_t(d, s, ts, idx, tau):
    """One-sided $t$ of $\\gamma$ in $d_k = $ quadratic $+ \\beta e^{-t_k/\\tau} + \\gamma F_\\tau[s - s_0]_k$."""
    K = idx.size
    tk = idx * ts
    x = tk / tk[-1] - 0.5
    X = np.stack([np.ones(K), x, x ** 2, np.exp(-tk / tau), lag_filter(s - s[0], ts, tau)[idx]], axis=1)
    X[:, -1] -= X[:, -1].mean()
    if np.ptp(X[:, -1]) < 1e-9:
        return -np.inf
    coef, *_ = np.linalg.lstsq(X, d[idx], rcond=None)
    r = d[idx] - X @ coef
    cov = np.linalg.pinv(X.T @ X) * float(r @ r) / (K - X.shape[1])
    return float(coef[-1] / math.sqrt(max(cov[-1, -1], 1e-300)))


def input_dependence(drift: np.ndarray, drive: np.ndarray, ts: float, step: int,
                     taus=BODY_TAUS, n_shifts: int = N_SHIFTS) -> float:
    """$z$ that a slow surroundings-like signal follows an input-driven one through a body.

    A stored-heat body warms with what drives it: its effect on the zones, seen as a drift of
    the surroundings $d(t)$, follows the first-order lag $F_\\tau$ of the input-driven
    temperature $s(t)$ (`drive`: the baseline's simulation, inputs only, never a measured
    temperature, which an exogenous drift would reach too), plus the decay of the body's
    initial state; an exogenous drift does not. At the drift's resolution (every `step`
    samples) $d_k = c_0 + c_1 t_k + c_2 t_k^2 + \\beta e^{-t_k/\\tau} + \\gamma F_\\tau[s - s_0]_k$ is
    fitted for each body time constant $\\tau$ in `taus`, and the statistic is the largest
    one-sided $t$ of $\\gamma$. A smooth drift's residuals are far from white, so the $t$ is not
    referred to Student's law but to the same statistic with the drive circularly shifted
    (`n_shifts` shifts spread over the record: same spectrum, no alignment with the drift); the
    rank p-value $(1 + \\#\\{t_m \\ge t\\})/(1 + M)$ is returned as a standard-normal $z$
    (0 when the record has fewer than 8 points to test).
    """
    d = np.asarray(drift, float)
    s = np.asarray(drive, float)
    idx = np.arange(0, d.size, max(int(step), 1))
    if idx.size < MIN_DEPENDENCE_POINTS or not (np.all(np.isfinite(d)) and np.all(np.isfinite(s))):
        return 0.0
    stat = lambda sig: max(_lag_t(d, sig, ts, idx, tau) for tau in taus)
    t0 = stat(s)
    if not np.isfinite(t0):
        return 0.0
    shifts = (np.arange(1, n_shifts + 1) * s.size) // (n_shifts + 1)
    null = np.array([stat(np.roll(s, int(k))) for k in shifts])
    p = (1.0 + np.sum(null >= t0)) / (1.0 + n_shifts)
    return float(norm.isf(p))


#: fewest points (drift knots) on which `input_dependence` tests anything
MIN_DEPENDENCE_POINTS = 8


def dependence_testable(T: int, step: int) -> bool:
    """Whether a record of `T` samples, tested every `step` samples, has the
    `MIN_DEPENDENCE_POINTS` that `input_dependence` needs (below them it returns 0: no evidence)."""
    return bool(math.ceil(T / max(int(step), 1)) >= MIN_DEPENDENCE_POINTS)


def records_dependence(drift: np.ndarray, drive: np.ndarray, lengths, ts: float,
                       step: int) -> tuple[list, list]:
    """`input_dependence` of each record of a concatenation `drift (sum T_r,)`, `drive` (records
    of `lengths` samples) on its own, and whether each is `dependence_testable`: each record's
    surroundings level, drift and body state are its own nuisances (the regression's level,
    trend and decay per record). On the concatenation the regression's level, trend and decay
    span every record, a body's wall restarts at each join unmodelled, and the circular shifts
    of the drive cross the joins: the statistic tests no record's hypothesis (two pooled records
    of an exogenous drift read 1.64 there, where the first alone reads 1.04 and the second is
    too short to test: a development case of the loop's set,
    `tests/diagnose/test_pooled_dependence.py`)."""
    edges = np.concatenate([[0], np.cumsum(lengths)]).astype(int)
    zs = [input_dependence(drift[a:b], drive[a:b], ts, step) for a, b in itertools.pairwise(edges)]
    return zs, [dependence_testable(int(T), step) for T in lengths]


def combined_dependence(zs, testable) -> float:
    """Stouffer's $z = \\sum_r z_r / \\sqrt{m}$ of the `input_dependence` statistics `zs` of the
    records that could be tested (`testable`, `m` of them; 0 when none): the estimation record's
    fitted drift and the drift re-estimated on the validation record test the same hypothesis on
    independent records (under an exogenous drift each $z$ is standard normal, so the sum over
    $\\sqrt m$ is too). A record too short to test adds nothing, so a designed validation record
    long enough to test can decide where the estimation record cannot, and a short one leaves the
    estimation record's statistic as it was. Combined, each $z$ is first clipped to the largest
    magnitude a rank p-value of `N_SHIFTS` shifts gives (a record whose drift lies below every
    shifted drive's, p = 1, is $-\\infty$ alone)."""
    z = [float(v) for v, ok in zip(zs, testable) if ok and not np.isnan(v)]
    if len(z) < 2:
        return z[0] if z else 0.0
    zb = float(norm.isf(1.0 / (1.0 + N_SHIFTS)))
    return float(sum(np.clip(z, -zb, zb)) / math.sqrt(len(z)))


def input_dependent(z_input: float) -> bool:
    """Whether a fitted surroundings drift follows the inputs (`input_dependence` $z$ at the
    one-sided `RIVAL_LEVEL`)."""
    return bool(z_input >= norm.isf(RIVAL_LEVEL))


def order_body_drift(rows: list, z_input: float) -> list:
    """`rows` (dicts with `mechanism`, best first) with `heat_accumulation` moved ahead of
    `ambient_variation` when the drift the latter fitted depends on the inputs
    (`input_dependent`): a body the heaters warm, not an exogenous drift. Otherwise unchanged:
    the test's power on a body whose time constant is near the record length is low (a drift
    first there was wrong on the development records' printer slow bodies), so
    no evidence of input dependence leaves the validation ranking, and `body_drift_tied` makes
    the other its rival."""
    return _body_ahead(rows) if input_dependent(z_input) else list(rows)


def _body_ahead(rows: list) -> list:
    """`rows` with `heat_accumulation` moved just ahead of an `ambient_variation` ranked before it."""
    names = [r["mechanism"] for r in rows]
    if "heat_accumulation" not in names or "ambient_variation" not in names:
        return list(rows)
    i, j = names.index("ambient_variation"), names.index("heat_accumulation")
    out = list(rows)
    if i < j:
        out.insert(i, out.pop(j))
    return out


def prefer_fewer_slow(rows: list, z_drift_over_body: float, k_body: int, k_drift: int) -> list:
    """`rows` (dicts with `mechanism`, best first) with `heat_accumulation` moved ahead of an
    `ambient_variation` named before it when the drift does not predict the validation record
    better than the body beyond the parameters it re-estimates there (`z_drift_over_body`: the
    `predictive_z` of the drift's residual against the body's, charged `k_drift - k_body`, below
    the one-sided `RIVAL_LEVEL`) and the body re-estimates fewer (`k_body < k_drift`).

    Both explain a slow component; the drift re-fits it on the validation record (a knot every
    `DRIFT_SPACING` s), the body predicts it from the inputs and its re-estimated initial state,
    so ranked by validation MSE the drift wins whenever it is not beaten. Of two explanations
    within the test's resolution the one with fewer parameters is named (as `prefer_identified`);
    the other stays its rival (`body_drift_tied`)."""
    return _body_ahead(rows) if k_body < k_drift and is_rival(z_drift_over_body) else list(rows)


def prefer_input_driven(rows: list, z_drift_over_body_est: float) -> list:
    """`rows` (dicts with `mechanism`, best first) with `heat_accumulation` moved ahead of an
    `ambient_variation` named before it when the drift does not fit the *estimation* record
    better than the body beyond the parameters it adds there (`z_drift_over_body_est`: the
    `predictive_z` of the drift's residual against the body's, charged the difference of their
    parameter counts, below the one-sided `RIVAL_LEVEL`).

    Both are fitted on that record with every parameter charged; on the validation record the
    drift re-estimates its knots and absorbs a body's decay, its misfit and the coloured noise
    alike, so a validation ranking favours it. Of two slow explanations the estimation record
    cannot separate, the one that predicts the slow part from the measured inputs (the body,
    warmed by the heaters) is named and the exogenous signal (re-estimated on every record)
    stays its rival (`body_drift_tied`); a drift the body cannot follow (one that cools the bed,
    or turns) beats it there and keeps its place. (Rule set on cases of development sets 14-18.)"""
    return _body_ahead(rows) if is_rival(z_drift_over_body_est) else list(rows)


def body_drift_tied(names, z_input: float) -> bool:
    """Both a slow body and a surroundings drift passed, and the drift's input dependence does
    not separate them: the one named second is the other's rival whatever the validation
    comparison says (a drift re-estimated on the validation record absorbs a body's decay)."""
    return bool("heat_accumulation" in names and "ambient_variation" in names
                and not input_dependent(z_input))


def slow_order_confidence(top: str, z_input: float) -> float:
    """Chance that `top`, the slow body (`heat_accumulation`) or the surroundings drift
    (`ambient_variation`) named ahead of the other, is the right one of the two, from the test
    of the body's defining property: $\\Phi(z)$ for the body, $\\Phi(-z)$ for the drift, $z$ the
    `input_dependence` statistic. Their validation comparison cannot: the drift's knots are
    re-estimated on the validation record (charged one unit each, the chance gain of a correct
    model), so a drift there absorbs whatever slow error a body's model leaves. A body named
    because the drift does not fit the estimation record better (`prefer_input_driven`) is a
    choice between explanations that record leaves tied, not evidence: near 0.5, uncertain."""
    z = float(z_input) if np.isfinite(z_input) else 0.0
    return float(norm.cdf(z if top == "heat_accumulation" else -z))


def confidence_runner(top: str, names, measured_var: bool):
    """Index in `names` (the other candidates that improved on the baseline, best first on the
    validation record) of the runner-up against which `top`'s confidence is measured
    (`confidence`), or None. A slow body or surroundings drift named first is not measured
    against the other of the two where the surroundings are not measured: the drift's knots are
    re-estimated on the validation record, so there it out-predicts a body it cannot be told
    from, and a body ordered first by the drift's input dependence would read as near-certainly
    wrong; the order of the two has its own confidence (`slow_order_confidence`)."""
    slow = ("heat_accumulation", "ambient_variation")
    skip = top in slow and not measured_var
    return next((i for i, m in enumerate(names) if not (skip and m in slow)), None)


def slow_rival(top: str, other_fits_estimation: bool, z_input: float) -> bool:
    """The other slow explanation is `top`'s rival: it improves the estimation record
    significantly (its likelihood-ratio test) and the drift's input dependence (`input_dependent`)
    does not decide for a body named first (nothing decides for a drift named first: the test
    can only show dependence)."""
    return bool(top in ("heat_accumulation", "ambient_variation") and other_fits_estimation
                and (top == "ambient_variation" or not input_dependent(z_input)))


__all__ = ["BODY_TAUS", "MIN_DEPENDENCE_POINTS", "N_SHIFTS", "body_drift_tied", "combined_dependence",
           "confidence_runner", "dependence_testable", "input_dependence", "input_dependent", "lag_filter",
           "order_body_drift", "prefer_fewer_slow", "prefer_input_driven", "records_dependence",
           "slow_order_confidence", "slow_rival"]
