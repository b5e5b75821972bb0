"""A stored-heat body as a restricted surroundings drift: its start from the fitted drift.

Per zone, the drift model is $\\dot x = -a\\,(x - L - d(t)) + b u$ and the body model
$\\dot x = -(a_b + c)(x - L) + c\\,(T_w - L) + b u$ with $\\tau_w \\dot T_w = \\bar T - T_w +
\\gamma (L - T_w)$ (`mechanisms.py`). They are the same zone when $a_b + c = a$ and
$c\\,(T_w - L) = a\\,d(t)$, and the body's wall, $W = T_w - L$, is the unit-gain lag $F_\\tau$
($\\tau = \\tau_w / (1 + \\gamma)$) of the bed's mean temperature plus the decay of its initial
state: $W = F_\\tau[\\bar T - L] / (1 + \\gamma) + W_0 e^{-t/\\tau}$. So the body is the drift
restricted to $d = \\kappa + \\alpha F_\\tau[\\bar T - L] + \\beta e^{-t/\\tau}$ ($\\kappa$ a level
shift), with $c = \\alpha a (1 + \\gamma)$ and $W_0 = \\beta a / c$: linear in
$(\\kappa, \\alpha, \\beta)$ for each $\\tau$. `body_from_drift` fits that restriction to a zone's
fitted drift (least squares over a grid of $\\tau$) and writes the body model it stands for: a
start for the body's own fit in the basin of a slow body that the neutral starts miss (a body
slower than the record, whose time constant and share trade along a long valley).
"""

from __future__ import annotations

import math

import numpy as np

from . import bodydrift as BD
from . import decide as D
from . import mechanisms as M
from . import starts as ST

#: effective body time constants tried (s), as multiples of the record length
TAU_GRID_RECORDS = np.geomspace(0.1, 4.0, 16)
#: largest body share of the zone's total loss a start takes, $c / a$
MAX_SHARE = 0.95


def body_from_drift(theta_drift, ybar, Phi, level, ts_free, ts, lay, taus=None):
    """Body starts `(n, P)` from the per-zone `ambient_variation` fits `theta_drift (n, P)`.

    `ybar (T,)` the measured mean zone temperature (what drives the per-zone body model's
    wall), `Phi (T, K)` the drift basis, `level`, `ts_free` as in the fits, `ts` (s). For each
    zone the drift $d$ (mean-free knots, as `simulate_zone` reads them) is fitted by
    $\\kappa + \\alpha F_\\tau[\\bar T - L] + \\beta e^{-t/\\tau}$ at each $\\tau$ of `taus` (default
    `TAU_GRID_RECORDS` record lengths), the best $\\tau$ with $\\alpha > 0$ (a wall the zones warm)
    kept, and the zone's start is the drift fit's heater gains and initial state with the body
    $c = \\alpha a (1 + \\gamma)$ (at most `MAX_SHARE` of $a$), $a_b = a - c$,
    $\\tau_w = \\tau (1 + \\gamma)$, $W_0 = \\beta a / c$, $\\gamma$ at its neutral start, the level
    moved by $\\kappa$ where it is free. Returns None when no zone's drift has a rising lag term
    (nothing a body explains)."""
    th = np.array(theta_drift, float)
    n, T = th.shape[0], ybar.shape[0]
    t = np.arange(T) * ts
    taus = TAU_GRID_RECORDS * T * ts if taus is None else np.asarray(taus, float)
    gam0 = 1.0                       # γ at its neutral start (`mechanisms.initial_theta`)
    out = th.copy()
    found = False
    for i in range(n):
        dr = th[i, lay.sl("drift")]
        d = Phi @ (dr - dr.mean())
        L = level + ts_free * th[i, lay.sl("ts0")][0]
        s = np.asarray(ybar, float) - L
        best = None
        for tau in taus:
            X = np.stack([np.ones(T), BD.lag_filter(s, ts, tau), np.exp(-t / tau)], axis=1)
            coef, *_ = np.linalg.lstsq(X, d, rcond=None)
            sse = float(np.sum((d - X @ coef) ** 2))
            if coef[1] > 0 and (best is None or sse < best[0]):
                best = (sse, tau, coef)
        if best is None:
            continue
        found = True
        _, tau, (kappa, alpha, beta) = best
        a = math.exp(th[i, lay.sl("log_a")][0])
        c = min(alpha * a * (1.0 + gam0), MAX_SHARE * a)
        out[i, lay.sl("log_a")] = math.log(a - c)
        out[i, lay.sl("log_c")] = math.log(c)
        out[i, lay.sl("log_tauw")] = math.log(max(tau * (1.0 + gam0) - M.TAUW_MIN, 1.0))
        out[i, lay.sl("log_gamma")] = -math.log(M.GAMMA_MAX / gam0 - 1.0)
        out[i, lay.sl("xw0")] = beta * a / c
        if ts_free:
            out[i, lay.sl("ts0")] += kappa
        out[i, lay.sl("drift")] = 0.0
    return out if found else None


def refit_body_from_drift(thc, res_c, cands, fit_sets, rec, level, ts_free, ts, lay, iters):
    """The `heat_accumulation` candidate's per-zone fits `thc[k]`, residuals `res_c[k]` (candidates
    in the order of `cands`) with each zone's fit replaced by the one from `body_from_drift`'s
    start (the `ambient_variation` candidate's fit, `rec` the estimation record's arrays:
    `ybar`, `Phi`) where that fits the record better: a body near or beyond the record length,
    whose time constant and share trade along a long valley that the neutral starts do not
    follow. `fit_sets(sets, starts, iters=...)` fits candidate sets; `iters` its iterations."""
    if "heat_accumulation" not in cands or "ambient_variation" not in cands:
        return thc, res_c
    sb = body_from_drift(thc[cands.index("ambient_variation")], rec.ybar, rec.Phi, level, ts_free, ts, lay)
    if sb is None:
        return thc, res_c
    thd, res_d = fit_sets([("heat_accumulation",)], sb[None], iters=iters)
    return ST.best_of_starts(np.concatenate([thc, thd]), np.concatenate([res_c, res_d]),
                            cands.index("heat_accumulation"), [len(cands)])


def order_by_parsimony(sig, e_c, cands, k_val, loc) -> list:
    """The significant candidates `sig` (best first) reordered by `bodydrift.prefer_fewer_slow`: an
    `ambient_variation` drift, which re-fits the slow part on the validation record, goes behind
    a `heat_accumulation` body that it does not out-predict there beyond its extra re-estimated
    parameters (`k_val(set)`); `e_c` the candidates' validation residuals (order of `cands`).
    Records the statistic in `loc["drift_over_body_z"]`."""
    if "heat_accumulation" not in cands or "ambient_variation" not in cands:
        return list(sig)
    kb, kd = ("heat_accumulation",), ("ambient_variation",)
    loc["drift_over_body_z"] = D.predictive_z(e_c[cands.index(kb[0])], e_c[cands.index(kd[0])],
                                              k_val(kd) - k_val(kb))
    return BD.prefer_fewer_slow(sig, loc["drift_over_body_z"], k_val(kb), k_val(kd))


def order_by_estimation(sig, res_c, cands, dof, loc) -> list:
    """The significant candidates `sig` (best first) reordered by `bodydrift.prefer_input_driven`: a
    `heat_accumulation` body goes ahead of an `ambient_variation` drift that does not fit the
    estimation record better beyond the parameters it adds (`dof(mechanism)`, the tests' degrees
    of freedom); `res_c` the candidates' estimation residuals (order of `cands`). Records the
    statistic in `loc["drift_over_body_estimation_z"]`."""
    if "heat_accumulation" not in cands or "ambient_variation" not in cands:
        return list(sig)
    kb, kd = "heat_accumulation", "ambient_variation"
    z = D.predictive_z(res_c[cands.index(kb)], res_c[cands.index(kd)], dof(kd) - dof(kb))
    loc["drift_over_body_estimation_z"] = z
    return BD.prefer_input_driven(sig, z)


__all__ = ["body_from_drift", "order_by_estimation", "order_by_parsimony", "refit_body_from_drift"]
