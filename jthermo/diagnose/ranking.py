"""The tests, the ranking and the top finding of a diagnosis.

`judge_candidates` puts every candidate through both tests of `decide.py` (a likelihood ratio on
the estimation record, a Diebold–Mariano comparison on the validation record, family-wise
false-alarm rate `decide.ALPHA`) and ranks them by their validation MSE (`Ranking`).
`order_significant` then orders the significant ones: a slow body and an unmeasured drift by
whether the drift follows the input-driven temperature (`bodydrift.py`: on the estimation
record's fitted drift and on the drift re-estimated on the validation record, combined over
the records long enough to test), failing that by parsimony (`slowbody.py`); a stored-heat
body whose time constant the record does not identify yields to a tied one-parameter
mechanism (`decide.prefer_identified`) and is not moved ahead by its estimation evidence
(`decide.promotable`, `decide.prefer_evidence`). `name_top` gives the top one's confidence and
its `rivals`: the explanations within the tests' resolution of it (`TopFinding`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import bodydrift as BD
from . import decide as D
from . import mechanisms as M
from .candidates import Candidates
from .prepare import Baseline, Localisation, Problem
from .slowbody import order_by_estimation, order_by_parsimony
from .validation import Validation

#: the slow explanations: a stored-heat body and an unmeasured surroundings drift
SLOW = ("heat_accumulation", "ambient_variation")


@dataclasses.dataclass(frozen=True)
class Ranking:
    """Every candidate's tests, best first by validation MSE, and the significant ones ordered."""
    table: list             # one row per candidate, in the candidates' order
    ranked: list            # the rows, best first by validation MSE reduction
    significant: list       # the significant rows not ruled out, ordered (`order_significant`)
    flagged: list           # significant findings the actuator's physics rules out
    forbidden: dict         # {mechanism: reason} ruled out
    extra: dict             # what `mechanisms.physical_parameters` needs beyond θ


def judge_candidates(pb: Problem, base: Baseline, locn: Localisation, cands: Candidates, vl: Validation,
                    forbidden: dict) -> Ranking:
    """Both tests of every candidate and the validation ranking; `forbidden` ({mechanism:
    reason}) the mechanisms the actuator rules out (a drift whose zones disagree joins them).
    `significant` is the validation ranking's significant rows (ordered by `order_significant`)."""
    vd, lay, n, K = vl.validator, pb.lay, pb.n, cands.K
    e_base, e_c = vl.e_base, vl.e_c
    base_fit = vd.fit_of(e_base)
    drops = locn.drops
    extra = {"delay": locn.delay, "period_s": locn.period * pb.ts if locn.period else float("nan"),
             "t_mean": pb.t_ref, "recoat_times_s": drops["times_s"] if locn.irregular else None,
             "ts_level": pb.level, "measured_ambient": pb.measured_var, "w_range": pb.w_range}
    table = []
    for k, m in enumerate(cands.names):
        zc, lc = D.thresholds(K, pb.dof(m))
        zv = D.predictive_z(e_base, e_c[k], vd.k_val((m,)))
        lr = D.likelihood_ratio(base.resid, cands.resid[k])
        fk = vd.fit_of(e_c[k])
        confirmed = zv >= zc
        if m == "recoat_cooling" and locn.irregular:
            # a loss differential concentrated in the few drops a validation record holds gives a
            # Diebold-Mariano z of at most about the square root of their number, however large
            # they are: confirmed by the likelihood ratio on the validation record instead, its
            # drops' flags counted as parameters fitted on it
            confirmed = D.likelihood_ratio(e_base, e_c[k]) >= D.thresholds(K, max(vd.flags, 1))[1]
        table.append({"mechanism": m, "validation_z": zv, "validation_z_critical": zc,
                      "estimation_lr": lr, "estimation_lr_critical": lc, "p_value": D.p_value(zv),
                      "significant": bool(confirmed and lr >= lc and D.not_worse(vd.yv, e_c[k], e_base)),
                      "val_mse": float(np.mean(e_c[k] ** 2)),
                      "val_reduction": float(1 - np.mean(e_c[k] ** 2) / np.mean(e_base ** 2)),
                      "mean_fit_percent": float(np.mean(fk)),
                      "fit_gain": float(np.mean(fk) - np.mean(base_fit)),
                      "parameters": M.physical_parameters(cands.theta[k], m, lay, pb.ts, extra), "k": k})
    # the tests decide what is significant; the size of the improvement (validation MSE) ranks
    ranked = sorted(table, key=lambda r: -r["val_reduction"] if np.isfinite(r["val_reduction"]) else np.inf)
    loc = locn.report
    if "ambient_variation" in cands.names and pb.amb is None and n > 1:
        # unmeasured surroundings are one temperature every zone sees: the zones' own drifts (the
        # per-zone fits) must agree, or the slow misfit the drift absorbs is something else
        loc["drift_agreement_z"] = D.common_drift_z(cands.theta_own[cands.index("ambient_variation")]
                                                    [:, lay.sl("drift")])
        lrs = loc.get("drift_own_vs_common_lr")
        if not (D.common_drift(loc["drift_agreement_z"])
                or (lrs is not None and not D.drift_contradicted(lrs, pb.n_knots))):
            forbidden = {**forbidden, "ambient_variation": "the zones' own fitted surroundings drifts do not "
                                                           "agree: not one surroundings signal"}
    flagged = [{"mechanism": r["mechanism"], "reason": forbidden[r["mechanism"]],
                "validation_z": r["validation_z"], "parameters": r["parameters"]}
               for r in ranked if r["significant"] and r["mechanism"] in forbidden]
    sig = [r for r in ranked if r["significant"] and r["mechanism"] not in forbidden]
    return Ranking(table=table, ranked=ranked, significant=sig, flagged=flagged, forbidden=forbidden, extra=extra)


def order_significant(pb: Problem, base: Baseline, locn: Localisation, cands: Candidates, vl: Validation,
                      rk: Ranking) -> Ranking:
    """`rk` with its significant rows ordered: the slow body and the drift by the drift's input
    dependence and parsimony, an unidentified body behind a tied one-parameter mechanism, and
    the strongest estimation evidence first among the explanations the validation leaves tied.
    Writes the input-dependence statistics to the localisation report."""
    sig, loc, e_c, ts, lay = rk.significant, locn.report, vl.e_c, pb.ts, pb.lay
    names = list(cands.names)
    if "ambient_variation" in names:
        # a slow body or a drift: the drift fitted on estimation follows the input-driven
        # (baseline-simulated) temperature through a lag only if it is a body (`bodydrift.py`)
        # (and, unmeasured, the drift re-estimated on the validation record follows the baseline's
        # simulation of that record: a designed record can show it). Each record is tested on
        # its own, with its own level, drift and body state as nuisances (concatenated, the test
        # is of no record: `bodydrift.records_dependence`); the records' tests are combined,
        # `bodydrift.combined_dependence`
        ka = names.index("ambient_variation")
        kstep = round(M.DRIFT_SPACING / ts)
        dr = np.median(cands.theta_own[ka][:, lay.sl("drift")], axis=0)
        z_r, ok_r = BD.records_dependence(pb.rec_e.Phi @ dr, base.yhat.mean(axis=1), pb.lengths or (pb.y.shape[0],),
                                          ts, kstep)
        n, kv = pb.n, vl.validator.kv
        dv = vl.rec_fit[1 + ka, 2 * n:2 * n + kv]
        z_v = (BD.input_dependence(vl.Phi @ (dv - dv.mean()), vl.yhat[0].mean(axis=1), ts, kstep)
               if not pb.measured_var else 0.0)
        loc["drift_input_dependence_records_z"] = [*z_r, z_v]
        loc["drift_input_dependence_z"] = BD.combined_dependence(
            [*z_r, z_v], [*ok_r, BD.dependence_testable(vl.Tv, kstep) and not pb.measured_var])
        sig = BD.order_body_drift(sig, loc["drift_input_dependence_z"])
        # and by parsimony: a drift re-fits the slow part on the validation record (`slowbody.py`)
        sig = order_by_parsimony(sig, e_c, names, vl.validator.k_val, loc)
        # and on the estimation record, where both are charged every parameter (`decide.py`)
        sig = order_by_estimation(sig, cands.resid, names, pb.dof, loc)
    if sig:
        # a body slower than the record, tied with an identified one-parameter mechanism: the latter
        k0 = sig[0]["k"]
        sig = D.prefer_identified(sig, pb.t_span, lambda r: D.is_rival(D.predictive_z(e_c[r["k"]], e_c[k0])),
                                  lambda m: M.n_added_per_zone(m, lay))
        # of the explanations the validation record leaves tied, the strongest on the estimation
        # record; a body the record does not identify is not moved ahead by it (its near-constant
        # heat term gains on the estimation record what `prefer_identified` just set aside)
        k0 = sig[0]["k"]
        sig = D.prefer_evidence(sig, lambda r: (D.promotable(r, pb.t_span)
                                                and D.is_rival(D.predictive_z(e_c[r["k"]], e_c[k0]))),
                                lambda r: pb.dof(r["mechanism"]))
    return dataclasses.replace(rk, significant=sig)


@dataclasses.dataclass(frozen=True)
class TopFinding:
    """The top significant candidate, its confidence and its rivals."""
    row: dict               # its `Ranking.table` row
    confidence: float
    rivals: list            # mechanisms within the tests' resolution of it
    others: list            # the other candidates that improved on the baseline, best first


def name_top(pb: Problem, cands: Candidates, vl: Validation, rk: Ranking, locn: Localisation) -> TopFinding | None:
    """The top of `rk.significant` (None: nothing significant), its confidence
    (`decide.confidence` against the runner-up, `bodydrift.confidence_runner`, on both records)
    and its rivals. Writes the runner-up's statistics to the localisation report."""
    sig, e_c, res_c, loc = rk.significant, vl.e_c, cands.resid, locn.report
    if not sig:
        return None
    top = sig[0]
    kt = top["k"]
    rivals = []
    tied = top["mechanism"] in SLOW and BD.body_drift_tied([r["mechanism"] for r in sig],
                                                           loc.get("drift_input_dependence_z", 0.0))
    for r in sig[1:]:
        if (D.is_rival(D.predictive_z(e_c[r["k"]], e_c[kt]))
                or (tied and r["mechanism"] in SLOW)):
            rivals.append(r["mechanism"])
    others = [r for r in rk.ranked if r is not top and r["val_reduction"] > 0]
    run = BD.confidence_runner(top["mechanism"], [r["mechanism"] for r in others], pb.measured_var)

    def z_est(r):
        """The top against another candidate on the estimation record, charged what it adds beyond it."""
        return D.predictive_z(res_c[r["k"]], res_c[kt], pb.dof(top["mechanism"]) - pb.dof(r["mechanism"]))

    z_run, z_run_est = None, None
    if run is not None:
        z_run, z_run_est = D.predictive_z(e_c[others[run]["k"]], e_c[kt]), z_est(others[run])
        loc["runner"] = {"mechanism": others[run]["mechanism"], "validation_z": z_run,
                         "estimation_z": z_run_est}
    conf = D.confidence(top["validation_z"], z_run, z_run_est)
    other_slow = next((r for r in rk.table if r["mechanism"] in SLOW and r is not top
                       and r["mechanism"] not in rk.forbidden), None)
    if other_slow is not None and not pb.measured_var:
        # a body or a drift: only the drift's input dependence separates them (`bodydrift.py`)
        z_in = loc.get("drift_input_dependence_z", 0.0)
        fits = other_slow["estimation_lr"] >= other_slow["estimation_lr_critical"]
        if BD.slow_rival(top["mechanism"], fits, z_in):
            rivals += [other_slow["mechanism"]] if other_slow["mechanism"] not in rivals else []
        if top["mechanism"] in SLOW and fits:
            conf = min(conf, (1.0 - D.p_value(top["validation_z"])) * BD.slow_order_confidence(top["mechanism"], z_in))
    if D.uncertain(conf):
        # not a confident name: every candidate that improved on the baseline and that the
        # top one does not beat, on the validation record or on the estimation one, is a
        # rival, significant alone or not
        rivals += [r["mechanism"] for r in others if r["mechanism"] not in rivals + [top["mechanism"]]
                   and (D.is_rival(D.predictive_z(e_c[r["k"]], e_c[kt])) or D.is_rival(z_est(r)))]
    return TopFinding(row=top, confidence=conf, rivals=rivals, others=others)


__all__ = ["SLOW", "Ranking", "TopFinding", "judge_candidates", "name_top", "order_significant"]
