"""Diagnosis: baseline fit, localisation, candidate refits, a stated-false-alarm test, ranking.

`diagnose(est, val)` fits the baseline grey-box bed model (isolated zones, every heater reaching
every zone, constant surroundings) by simulation-error PEM, locates its residuals, refits one
augmented model per mechanism of the library (`mechanisms.py`; those that need neighbours only
when there are two zones or more), and keeps a mechanism only if it passes the two tests of
`decide.py` (a likelihood ratio on the estimation record, a Diebold–Mariano comparison on the
validation record, whitened residuals, family-wise false-alarm rate `decide.ALPHA`): the
augmented model has to predict a record it was not fitted on, where only initial states (and
the surroundings level when no surroundings signal is measured, for every model alike), and for
`ambient_variation` the unmeasured surroundings drift, are re-estimated (and charged for).

The diagnosis runs as named stages, each passing a small frozen record to the next:

| stage | module | record |
| --- | --- | --- |
| the records read once | `prepare.prepare` | `Problem` |
| the first-order baseline | `prepare.fit_baseline_stage` | `Baseline` |
| localisation, recoat events, dead-time scan | `prepare.localise_stage` | `Localisation` |
| one per-zone refit per mechanism | `candidates.fit_candidates` | `Candidates` |
| every model simulated coupled on the validation record | `validation.validate_candidates` | `Validation` |
| both tests, the validation ranking | `ranking.judge_candidates` | `Ranking` |
| the significant ones ordered (body or drift, parsimony, evidence) | `ranking.order_significant` | `Ranking` |
| the top finding's confidence and rivals | `ranking.name_top` | `TopFinding` |
| the augmented model, jointly fitted, grown forward | `augment.combine` | `Augmented` |
| the report | `report_dict` | the JSON-ready dict |

The localisation report (`Localisation.report`) is the one dict the stages add figures to.
"""

from __future__ import annotations

import time

import numpy as np

from .. import runtime
from ..errors import ConfigError, DataError
from . import decide as D
from . import mechanisms as M
from . import pool as PL
from .augment import Augmented, baseline_only, combine
from .candidates import Candidates, ZoneFits, fit_candidates
from .checks import as_records, check_records, pool_records
from .describe import mechanism_evidence, summary
from .joint import RESTRICT_ABOVE, rivals_among
from .prepare import Baseline, Localisation, Problem, fit_baseline_stage, localise_stage, prepare
from .ranking import Ranking, TopFinding, judge_candidates, name_top, order_significant
from .validation import Validation, validate_candidates

#: longest dead time tried, in samples (and at least `MAX_DELAY_S` seconds when that is more)
MAX_DELAY = 12
MAX_DELAY_S = 12.0
#: step of the dead-time scan, in samples (the fit then moves the delay continuously)
DELAY_STEP = 0.5
#: most baseline refits of the dead-time scan (`prepare.scan_delay`: the baseline refitted with
#: its inputs delayed by the scan's best, scanned again until the best stays)
DELAY_REFITS = 3
#: mechanisms that need at least two zones
NEEDS_NEIGHBOURS = ("lateral_conduction",)
#: actuators whose physics rules a mechanism out: a finding of it is flagged, not headlined
ACTUATORS = {"resistive-pwm": {"input_nonlinearity": "a PWM-driven resistive heater's mean power is linear "
                                                     "in the duty cycle"},
             "any": {}}
#: most Levenberg–Marquardt iterations of a per-zone candidate fit (each stops once converged,
#: `fitting.RTOL`). An unconverged fit misjudges its mechanism's evidence: at 25 many fits
#: stopped short, and at 60 a zone with many heater gains (N = 4-9) or a slow body's long valley
#: still did, so that slow bodies were named `ambient_variation`; at 200 they are named and the
#: null records stay quiet, for more CPU per diagnosis (measured by `python
#: experiments/diagnose_heldout_hard.py` and `python benchmarks/latency.py --only diagnose`).
#: Fewer would move the answers: a looser `fitting.RTOL`, a cap of 100 or no extra body starts
#: shift candidates' estimation statistics by hundreds to thousands (measured by
#: `python benchmarks/diagnose_zone_convergence.py`, the `fitting` module's note)
N_ITER = 200
#: at most this many more `n_iter` rounds for the zone fits still falling at the cap
#: (`fitting.still_falling`; the others stop): a 7-zone lamp record was named `radiative_loss`
#: at 0.999 against a lamp fit whose heater gains revive only after 200-800 iterations, and is
#: named `input_nonlinearity` with 800
CONTINUE_ROUNDS = 3
#: Levenberg–Marquardt iterations of a joint fit (it starts from `joint_start`: the separable
#: grid at the surroundings level, every mechanism at its neutral value)
JOINT_ITER = 25
#: most iterations of the common surroundings drift's fit (`commondrift.common_drift_fit`; it stops
#: once converged, `fitting.RTOL`): the tests of agreement compare it with the zones' own drifts,
#: so an unconverged common fit reads as zones that contradict one drift
COMMON_DRIFT_ITER = 200
#: iterations of the body's fit from the drift's start, in `n_iter` (a long valley: `slowbody.py`)
BODY_ITER_FACTOR = 2
#: relative difference of the two records' sample times accepted as the same sample time
TS_TOLERANCE = 0.01



def diagnose(est, val, *, seed: int = 0, progress=None, mechanisms=M.MECHANISMS,
             n_iter: int = N_ITER, actuator: str = "any") -> dict:
    """Find what the baseline grey-box bed model leaves out, refit, and say how much it helps.

    **Arguments:**
    - `est`, `val`: `IOData` records (inputs = heater commands, outputs = zone temperatures,
      optional `w_ambient` surroundings in °C; other signals are ignored). Fits are simulation
      fits on `val`. `est` may be a list of records of one plant (any lengths and inputs, the
      same signals and sample time): they are fitted jointly (`pool.py`: shared physical
      parameters, each record its own initial state, surroundings level and drift), every test
      is on their pooled residuals, and each finding reports each record's share of its
      evidence (`evidence.records`).
    - `seed`: accepted for the common interface; the procedure is deterministic.
    - `progress`: optional callback `progress(i, total, info)`.
    - `mechanisms`: the candidates tried (default: the whole library; those in
      `NEEDS_NEIGHBOURS` are left out of a one-zone record).
    - `actuator`: a key of `ACTUATORS`; a finding its physics rules out is reported under
      `flagged` (with the reason), not named.

    **Returns:** the JSON-ready report dict: `verdict`, `baseline`, `findings` (ranked),
    `augmented`, plus `localisation` and `candidates` (every refit's figures) and `seconds`.
    """
    runtime.guard()     # a long-lived process stays below the memory-map bound
    t_start = time.perf_counter()
    records, est, val, dropped = pool_records(as_records(est), val, TS_TOLERANCE)
    check_records(est, val, TS_TOLERANCE)
    mechanisms = tuple(mechanisms)
    for m in mechanisms:
        if m not in M.MECHANISMS:
            raise DataError(f"diagnose: unknown mechanism `{m}` (known: {', '.join(M.MECHANISMS)})")
    if actuator not in ACTUATORS:
        raise DataError(f"diagnose: unknown actuator `{actuator}` (known: {', '.join(ACTUATORS)})")
    if est.n_outputs < 2:
        mechanisms = tuple(m for m in mechanisms if m not in NEEDS_NEIGHBOURS)
    if not mechanisms:
        raise ConfigError("diagnose: no candidate mechanism left to try (neighbour mechanisms "
                          "need at least two zones)")
    stages = ("baseline", "localisation", "candidates", "validation", "combination", "done")

    def tick(i):
        runtime.guard()     # between stages too: one diagnosis compiles ~3,500 maps of programs
        if progress is not None:
            progress(i + 1, len(stages), {"stage": stages[i]})

    pb = prepare(records, est, val, mechanisms)
    base = fit_baseline_stage(pb)
    tick(0)
    locn = localise_stage(pb, base, MAX_DELAY, MAX_DELAY_S, DELAY_STEP, DELAY_REFITS)
    tick(1)
    fits = ZoneFits(pb=pb, events=locn.events, delay=locn.delay, n_iter=n_iter, rounds=CONTINUE_ROUNDS)
    cands = fit_candidates(pb, base, locn, fits, BODY_ITER_FACTOR * n_iter, COMMON_DRIFT_ITER)
    tick(2)
    vl = validate_candidates(pb, base, locn, cands)
    tick(3)
    rk = judge_candidates(pb, base, locn, cands, vl, ACTUATORS[actuator])
    rk = order_significant(pb, base, locn, cands, vl, rk)
    top = name_top(pb, cands, vl, rk, locn)
    aug = (baseline_only(base, vl) if top is None
           else combine(pb, locn, cands, vl, rk, top, JOINT_ITER, RESTRICT_ABOVE))
    tick(4)
    result = report_dict(pb, base, locn, cands, vl, rk, top, aug, dropped, time.perf_counter() - t_start)
    tick(5)
    return result


def findings_of(pb: Problem, locn: Localisation, cands: Candidates, vl: Validation, rk: Ranking,
                top: TopFinding | None, aug: Augmented, base: Baseline) -> list:
    """The report's findings: the augmented model's mechanisms, the top first, each with its
    confidence, rivals, zones, evidence and physical parameters."""
    n, lay, e_base, e_c = pb.n, pb.lay, vl.e_base, vl.e_c
    noise = D.sensor_noise(vl.validator.yv - aug.yhat)
    findings = []
    for rank, mech in enumerate(aug.chosen):
        row = next(r for r in rk.table if r["mechanism"] == mech)
        dz = np.mean(e_base ** 2, axis=0) - np.mean(e_c[row["k"]] ** 2, axis=0)
        zones = [i + 1 for i in range(n) if dz[i] >= 0.5 * dz.max()] if dz.max() > 0 else list(range(1, n + 1))
        params = M.physical_parameters(aug.theta, mech, lay, pb.ts, rk.extra)
        if rank == 0:
            conf, mech_rivals = top.confidence, top.rivals
            effect = D.rms(vl.yhat[0] - vl.yhat[row["k"] + 1])
        else:
            # an addition tied with others of its round is named with them as its rivals
            acc = next(a for a in aug.added if a["accepted"] and a["mechanisms"][-1] == mech)
            tie = rivals_among(acc.get("z_over", {}), aug.chosen)
            conf = D.confidence(acc["validation_z"], tie["z_over_runner"])
            mech_rivals = tie["rivals"]
            effect = acc["effect_rms_C"]
        small = D.below_noise(effect, noise)
        evidence = {"validation_z": round(row["validation_z"], 3),
                    "validation_z_critical": round(row["validation_z_critical"], 3),
                    "estimation_likelihood_ratio": round(row["estimation_lr"], 2),
                    "estimation_lr_critical": round(row["estimation_lr_critical"], 2),
                    "p_value": row["p_value"],
                    "validation_mse_reduction_percent": round(100 * row["val_reduction"], 2),
                    "validation_fit_gain_points": round(row["fit_gain"], 2),
                    "runner_up": next((r["mechanism"] for r in rk.ranked if r["mechanism"] != mech), None),
                    "zone_mse_reduction": [round(float(v), 5) for v in dz],
                    "effect_rms_C": round(effect, 4), "sensor_noise_C": round(noise, 4)}
        if pb.lengths:     # each pooled record's share of the estimation evidence (`pool.py`)
            evidence["records"] = PL.evidence_shares(base.resid, cands.resid[row["k"]], pb.lengths)
        evidence.update(mechanism_evidence(mech, locn.report, locn.periodic,
                                           locn.drops if locn.irregular else None))
        findings.append({"mechanism": mech, "confidence": float(conf), "zones": zones,
                         "summary": summary(mech, zones, params, D.uncertain(conf), mech_rivals,
                                            (effect, noise) if small else None),
                         "below_noise": small,
                         "evidence": evidence,
                         "parameters": params, "rivals": mech_rivals,
                         "uncertain": bool(D.uncertain(conf))})
    return findings


def report_dict(pb: Problem, base: Baseline, locn: Localisation, cands: Candidates, vl: Validation,
                rk: Ranking, top: TopFinding | None, aug: Augmented, dropped, seconds: float) -> dict:
    """The JSON-ready report, with the arrays (`_arrays`) and fitted models (`_models`) the
    report and the experiment design read (not JSON: dropped by `to_json`)."""
    vd, lay, e_base = vl.validator, pb.lay, vl.e_base
    findings = findings_of(pb, locn, cands, vl, rk, top, aug, base)
    e_aug = vd.yv - aug.yhat
    aug_fit, base_fit = vd.fit_of(e_aug), vd.fit_of(e_base)
    chosen = aug.chosen
    sae = lambda e: float(np.sum(np.abs(e))) if np.all(np.isfinite(e)) else float("nan")
    result = {
        "verdict": "mismatch" if findings else "no_significant_mismatch",
        "decision": {"test": "whitened likelihood ratio (estimation) and Diebold-Mariano (validation)",
                     "family_false_alarm_rate": D.ALPHA, "candidates_tested": cands.K},
        "baseline": {"model": "greybox (isolated zones, full heater gains, constant surroundings)",
                     "mean_fit_percent": float(np.mean(base_fit)),
                     "fit_percent": [float(v) for v in base_fit], "sum_abs_error": sae(e_base)},
        "findings": findings,
        "flagged": rk.flagged,
        "inputs_left_out": [f"u_{nm}" for nm in dropped],
        "estimation_records": [{"samples": d.n_samples, "duration_s": d.n_samples * pb.ts} for d in pb.records],
        "augmented": {"mechanisms": list(chosen),
                      "fit": aug.fit.get("fit", "joint (all zones, coupled simulation error)") if chosen
                      else "baseline",
                      "surroundings": aug.level_mode,
                      "surroundings_test": aug.fit.get("level_test") if chosen else None,
                      "mean_fit_percent": float(np.mean(aug_fit)),
                      "fit_percent": [float(v) for v in aug_fit], "sum_abs_error": sae(e_aug),
                      "parameters": {m: M.physical_parameters(aug.theta, m, lay, pb.ts, rk.extra)
                                     for m in chosen}},
        "localisation": locn.report,
        "candidates": [{k: (round(v, 6) if isinstance(v, float) else v) for k, v in r.items()
                        if k != "k"} for r in rk.ranked],
        "combinations": aug.added,
        "seconds": seconds,
    }
    names = cands.names
    result["_arrays"] = {"yhat_baseline": vl.yhat[0], "yhat_augmented": aug.yhat, "resid_est": base.resid,
                         "resid_est_candidates": {m: cands.resid[k] for k, m in enumerate(names)},
                         "resid_val": {"baseline": e_base, **{m: vl.e_c[k] for k, m in enumerate(names)}},
                         "k_val": {m: vd.k_val((m,)) for m in names}}
    # the fitted single-mechanism models and what simulating them needs (`experiment.py`)
    result["_models"] = {"theta": {"baseline": base.theta, **{m: cands.theta[k] for k, m in enumerate(names)}},
                         "layout": lay, "level": pb.level, "ts_free": pb.ts_free, "t_ref": pb.t_ref,
                         "delay": locn.delay, "measured_ambient": pb.measured_var, "period": locn.period,
                         "zone_phase": locn.periodic.get("zone_phase"), "inputs_left_out": dropped}
    return result


def to_json(result: dict) -> dict:
    """The result without its report arrays (keys starting with `_`)."""
    return {k: v for k, v in result.items() if not k.startswith("_")}


__all__ = ["diagnose", "to_json"]
