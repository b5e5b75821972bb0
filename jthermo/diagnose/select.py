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
Significant candidates are ranked by their validation MSE (a stored-heat body whose time
constant the record does not identify yields to a tied one-parameter mechanism,
`decide.prefer_identified`, and is not moved ahead by its estimation evidence,
`decide.promotable`); a slow body and an unmeasured drift are ordered by whether the drift
follows the input-driven temperature, tested on the estimation record's fitted drift and on the
drift re-estimated on the validation record, combined over the records long enough to test
(`bodydrift.combined_dependence`: a long designed validation record can settle the pair), and
failing that by parsimony (a drift that does not out-predict the body beyond the knots it
re-estimates on the validation record goes behind it, `bodydrift.prefer_fewer_slow`, and so does
one that does not fit the estimation record better beyond the parameters it adds,
`bodydrift.prefer_input_driven`; the body is also fitted from the drift restricted to its form,
`slowbody.py`);
explanations within the test's resolution of the top one are reported as its `rivals`.

The candidate tests fit per zone (series-parallel form): zone i's model sees its neighbours' and
the bed's measured temperatures, so all zones and candidates are independent small problems
solved by the compiled masked Levenberg–Marquardt (`fitting.fit_zones`); the validation
fit then simulates all zones coupled. Where the surroundings are not measured,
`ambient_variation` is then refitted with one drift for all zones (`commondrift.common_drift_fit`): a
zone's own drift is not identified. The augmented model is then refitted *jointly* over all
zones (coupled simulation error, `fitting.fit_joint`: zones interact through their simulated
temperatures and the fitted exchange), with the surroundings at the record's rest level (its
first sample: the heaters were off before it) unless both tests demand a fitted level, and grown
by forward selection (up to `MAX_COMBINED` mechanisms): every other candidate may join,
significant alone or not (radiation shows only once the surroundings sit at their level, a
coupling only behind a lag); an addition is kept only if it passes both tests against the
smaller joint model, and of those that pass the one with the strongest estimation evidence
(smallest χ² tail of its likelihood ratio) joins.
"""

from __future__ import annotations

import math
import time

import jax.numpy as jnp
import numpy as np

from .. import runtime
from ..errors import ConfigError, DataError
from ..models.greybox import first_order_start
from . import bodydrift as BD
from . import decide as D
from . import mechanisms as M
from . import pool as PL
from . import starts as ST
from .commondrift import common_drift_fit
from .checks import as_records, check_records, pool_records
from .describe import mechanism_evidence, summary
from .fitting import fit_records, fit_zones, sim_zones, still_falling
from .joint import (
    RESTRICT_ABOVE,
    JointFits,
    forward_select,
    grid_start,
    joint_active,
    joint_start,
    pruned_start,
    restricted_active,
    rivals_among,
)
from .localise import localise
from .recoat import estimation_events, validation_events
from .slowbody import order_by_estimation, order_by_parsimony, refit_body_from_drift
from .stages import (ambient_column as _ambient_column, fit_baseline, fit_percent as _fit_percent,
                     problems as _problems, record_arrays, record_starts, shared as _shared,
                     simulate_baseline)

#: longest dead time tried, in samples (and at least `MAX_DELAY_S` seconds when that is more)
MAX_DELAY = 12
MAX_DELAY_S = 12.0
#: step of the dead-time scan, in samples (the fit then moves the delay continuously)
DELAY_STEP = 0.5
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
    lengths = tuple(d.n_samples for d in records) if len(records) > 1 else ()
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
    step = [0]
    total = 6

    def tick(info):
        step[0] += 1
        if progress is not None:
            progress(step[0], total, info)

    ts = float(est.ts)
    y, u = np.asarray(est.y, float), np.asarray(est.u, float)
    T, n = y.shape
    nu = u.shape[1]
    amb = _ambient_column(est)
    if amb is not None and _ambient_column(val) is None:
        amb = None
    if amb is not None:
        level = float(np.mean(est.w[:, amb]))
        ts_free = 0.0
        w_range = float(np.ptp(np.concatenate([est.w[:, amb], val.w[:, amb]])))
        measured_var = w_range > 0.05
    else:
        level = None
        ts_free = 1.0
        measured_var = False
        w_range = 0.0
    # per-zone first-order starts (rates: capacity 1)
    _loss, _gain, surr = first_order_start(y, u, None if amb is None else
                                         np.full((T, 1), level), ts, 1.0)
    if level is None:
        level = surr
    n_knots = PL.drift_basis(lengths, ts)[0].shape[1] if lengths else M.n_drift_knots(T, ts)
    lay = M.make_layout(n, nu, n_knots, lengths)
    # the longest record: what identifies a slow body's time constant (pooled records are not
    # one long record)
    t_span = (max(lengths) if lengths else T) * ts
    rec_e = record_arrays(est, amb, level, n_knots, lengths)
    rec_v = record_arrays(val, amb, level, M.n_drift_knots(val.n_samples, ts))
    if not measured_var:
        rec_e["wdev"][:] = 0.0
        rec_v["wdev"][:] = 0.0
    t_ref = float(y.mean())      # °C: where the radiative share is defined
    sh_e = _shared(rec_e, level, ts_free, ts, t_ref)
    base_names = ["log_a", "log_b", "x0", "x0_rec"] + (["ts0", "ts0_rec"] if ts_free else [])
    base_mask = lay.mask(base_names)
    ga, gb, gx, gs = grid_start(y, u, ts, level, ts_free)
    th0 = np.stack([M.initial_theta(lay, log_a=ga[i], log_b=np.log(gb[i]), x0=gx[i], ts0=gs[i],
                                    xw0=(y[0].mean() - level) / 2.0)
                    for i in range(n)])
    th0 = record_starts(th0, y, level, lengths, lay)

    # ---- 1. baseline (first order: variable projection in NumPy, `baseline.py`) -------------
    thb = fit_baseline(th0, y, u, ts, level, ts_free, lay)
    yb_e = simulate_baseline(thb, rec_e, ts, level, ts_free, lay)
    R_e = y - yb_e
    tick({"stage": "baseline"})

    # ---- 2. localisation, periodic events, dead time ----------------------------------------
    loc = localise(R_e, y, u, ts)
    # recoat drops, periodic or at any times (`recoat.py`)
    rc = estimation_events(R_e, np.exp(thb[:, lay.sl("log_a")][:, 0]), ts, loc)
    ev_e, P, irregular, per_ev, drops = rc["events"], rc["period"], rc["irregular"], rc["periodic"], rc["drops"]
    # dead time: simulate the baseline with each delay on a grid of fractions of a sample
    max_d = min(M.PAD - 3.0, max(float(MAX_DELAY), math.ceil(MAX_DELAY_S / ts)))
    dgrid = np.arange(DELAY_STEP, max_d + 1e-9, DELAY_STEP)
    dcost = np.array([np.mean((y - simulate_baseline(thb, rec_e, ts, level, ts_free, lay, d)) ** 2)
                      for d in dgrid])
    best_delay = float(dgrid[int(np.argmin(dcost))])
    loc["delay_scan"] = {"delays_s": (dgrid * ts).tolist(), "cost": dcost.round(6).tolist(),
                         "baseline_cost": float(np.mean(R_e ** 2))}
    tick({"stage": "localisation"})

    def fit_sets(sets, starts, n_act=None, iters=None):
        """Fit one augmented model per mechanism set on the estimation record: (θ, residuals);
        `n_act` (static) the most free parameters of one problem (default: the sets' own),
        `iters` the Levenberg–Marquardt iterations (default `n_iter`)."""
        S = len(sets)
        masks = np.concatenate([np.tile(np.minimum(base_mask + sum(lay.mask(M.MECH_PARAMS[m]) for m in st),
                                                   1.0), (n, 1)) for st in sets])
        ons = jnp.asarray(np.concatenate([np.tile(M.on_vector(st), (n, 1)) for st in sets]))
        per_s = _problems(rec_e, S, events=np.stack([ev_e] * S),
                          delays=[best_delay if "input_delay" in st else 0.0 for st in sets])
        if n_act is None:
            n_act = 4 * math.ceil(masks.sum(axis=1).max() / 4)      # fewer distinct compilations
        its, masks = n_iter if iters is None else iters, jnp.asarray(masks)
        th, _, hist = fit_zones(jnp.asarray(starts.reshape(S * n, -1)), masks, ons, per_s, sh_e, lay, its, n_act)
        for _ in range(CONTINUE_ROUNDS):       # fits still falling at the cap go on (`fitting.py`)
            more = still_falling(hist, T)
            if not more.any():
                break
            th, _, hist = fit_zones(th, masks, ons, per_s, sh_e, lay, its, n_act, more * its)
        ys = np.asarray(sim_zones(th, ons, per_s, sh_e, lay)).reshape(S, n, T).transpose(0, 2, 1)
        return np.asarray(th).reshape(S, n, -1), y[None] - ys

    # ---- 3. one refit per mechanism -----------------------------------------------------------
    cands = list(mechanisms)
    K = len(cands)
    # mechanism parameters start at their neutral values (baseline parameters kept)
    neutral = np.stack([M.initial_theta(lay, log_a=thb[i, lay.sl("log_a")][0],
                                        log_b=thb[i, lay.sl("log_b")], x0=thb[i, lay.sl("x0")][0],
                                        ts0=thb[i, lay.sl("ts0")][0],
                                        xw0=(y[0].mean() - level - thb[i, lay.sl("ts0")][0]) / 2.0)
                        for i in range(n)])
    neutral = record_starts(neutral, y, level, lengths, lay)
    for grp in ("x0_rec", "ts0_rec"):          # pooled records: each its own, as the baseline's
        neutral[:, lay.sl(grp)] = thb[:, lay.sl(grp)]
    # a stored-heat body also from slow starts (`starts.body_starts`), radiation from steeper
    # shares (`starts.rad_starts`), each zone its best (its smallest estimation cost)
    extra_starts = {m: f(neutral, lay) for m, f in (("heat_accumulation", ST.body_starts),
                                                    ("radiative_loss", ST.rad_starts)) if m in cands}
    thc, res_c = fit_sets([(m,) for m in cands] + [(m,) for m, st in extra_starts.items() for _ in st],
                          np.stack([neutral] * K + [t for st in extra_starts.values() for t in st]))
    for m, st in extra_starts.items():   # each call drops its extra fits: the next group's are at K
        thc, res_c = ST.best_of_starts(thc, res_c, cands.index(m), range(K, K + len(st)))
    # and from the fitted drift restricted to a body's form (`slowbody.body_from_drift`)
    thc, res_c = refit_body_from_drift(thc, res_c, cands, fit_sets, rec_e, level, ts_free, ts, lay,
                                       BODY_ITER_FACTOR * n_iter)
    thc_own = thc
    if "ambient_variation" in cands and amb is None and n > 1:
        # unmeasured surroundings: one drift for every zone (`commondrift.common_drift_fit`); the zones'
        # own drifts are kept for the tests of agreement and input dependence below. Where a
        # surroundings column is measured (constant), the per-zone drifts stay: there an estimated
        # drift contradicts the measurement, and the common one outranked a shared body in the
        # in-class study (`accumulation`, 6 zones)
        ka = cands.index("ambient_variation")
        thc, res_c = np.array(thc), np.array(res_c)
        res_own = res_c[ka].copy()
        thc[ka], res_c[ka] = common_drift_fit(thc[ka], y, sh_e, level, ts_free, lay, COMMON_DRIFT_ITER,
                                              CONTINUE_ROUNDS)
        loc["drift_own_vs_common_lr"] = [D.likelihood_ratio(res_c[ka][:, i:i + 1], res_own[:, i:i + 1])
                                         for i in range(n)]
    tick({"stage": "candidates"})

    # ---- 4. validation: simulate every model coupled, initial states re-estimated -----------------
    Tv = val.n_samples
    yv = np.asarray(val.y, float)
    kv = M.n_drift_knots(Tv, ts)
    Phi_v = M.drift_basis(Tv, ts, kv)
    sh_v = _shared({"u": rec_v["u"], "wdev": rec_v["wdev"], "Phi": Phi_v, "u_pad": rec_v["u_pad"]},
                   level, ts_free, ts, t_ref)
    # recoat events on the validation record, found again on its own residuals (`recoat.py`)
    ev_v, flags_v = np.zeros((Tv, n)), 0
    if P or irregular:
        thb_v = thb.copy()
        thb_v[:, lay.sl("x0")] = yv[0][:, None]
        ybv = simulate_baseline(thb_v, rec_v, ts, level, ts_free, lay)
        ev_v, flags_v = validation_events(yv - ybv, rc, ts, loc)

    def validate(models, with_rec=False):
        """Coupled simulations `(M, Tv, n)` of models on the validation record: (θ, mechanism set)
        pairs fitted per zone (surroundings as the baseline's), or (θ, set, setup) for the joint
        fits (`JointFits.setup` of the validation record); `with_rec`: also the record parameters
        re-estimated on it `(M, 2 n + kv + 1)` (initial states, body states, drift knots, level)."""
        Mn = len(models)
        R = 2 * n + kv + 1              # + the record's own surroundings level (when not measured)
        rec0, rmask = np.zeros((Mn, R)), np.zeros((Mn, R))
        per_zone = {"ts_level": level, "ts_free": ts_free, "u_pad": rec_v["u_pad"]}
        setups = [m[2] if len(m) == 3 else per_zone for m in models]
        lev_m = np.array([su["ts_level"] for su in setups])
        free_m = np.array([su["ts_free"] for su in setups])
        for j, (m, su) in enumerate(zip(models, setups)):
            th, st = m[0], m[1]
            rec0[j, :n] = yv[0]
            _, gam = M.wall_parameters(th[:, lay.sl("log_tauw")][:, 0], th[:, lay.sl("log_gamma")][:, 0])
            tsl = lev_m[j] + free_m[j] * float(np.median(th[:, lay.sl("ts0")][:, 0]))
            rec0[j, n:2 * n] = tsl + (rec0[j, :n].mean() - tsl) / (1.0 + gam)
            rmask[j, :n] = 1.0
            rmask[j, n:2 * n] = float("heat_accumulation" in st)
            rmask[j, 2 * n:2 * n + kv] = float("ambient_variation" in st and not measured_var)
            rmask[j, -1] = free_m[j]
        fper = {"events": jnp.asarray(np.stack([ev_v] * Mn)),
                "delay": jnp.asarray(np.array([best_delay if "input_delay" in m[1] else 0.0
                                               for m in models])),
                **{k: jnp.asarray(np.stack([su[k] for su in setups], dtype=float)) for k in per_zone}}
        rec_fit, yh, _ = fit_records(jnp.asarray(np.stack([m[0] for m in models])),
                               jnp.asarray(np.stack([M.on_vector(m[1]) for m in models])),
                               jnp.asarray(rec0), jnp.asarray(rmask), jnp.asarray(yv), fper, sh_v, lay, 10)
        return (np.asarray(yh), np.asarray(rec_fit)) if with_rec else np.asarray(yh)

    def k_val(st):
        """Parameters re-estimated on the validation record beyond the zones' initial states."""
        return (n * ("heat_accumulation" in st) + kv * ("ambient_variation" in st and not measured_var)
                + flags_v * ("recoat_cooling" in st))

    yhat_v, rec_v_fit = validate([(thb, ())] + [(thc[k], (m,)) for k, m in enumerate(cands)], with_rec=True)
    e_base = yv - yhat_v[0]
    e_c = [yv - yhat_v[k + 1] for k in range(K)]
    tick({"stage": "validation"})

    # ---- 5. the tests, ranking, rivals --------------------------------------------------------
    fit_of = lambda e: _fit_percent(yv, yv - e) if np.all(np.isfinite(e)) else np.full(n, np.nan)
    base_fit = fit_of(e_base)
    extra = {"delay": best_delay, "period_s": P * ts if P else float("nan"), "t_mean": t_ref,
             "recoat_times_s": drops["times_s"] if irregular else None,
             "ts_level": level, "measured_ambient": measured_var, "w_range": w_range}
    forbidden = ACTUATORS[actuator]
    dof = lambda m: M.n_added(m, lay, shared_drift=amb is None)    # the tests' degrees of freedom
    table = []
    for k, m in enumerate(cands):
        zc, lc = D.thresholds(K, dof(m))
        zv = D.predictive_z(e_base, e_c[k], k_val((m,)))
        lr = D.likelihood_ratio(R_e, res_c[k])
        fk = fit_of(e_c[k])
        confirmed = zv >= zc
        if m == "recoat_cooling" and irregular:
            # a loss differential concentrated in the few drops a validation record holds gives a
            # Diebold-Mariano z of at most about the square root of their number, however large
            # they are: confirmed by the likelihood ratio on the validation record instead, its
            # drops' flags counted as parameters fitted on it
            confirmed = D.likelihood_ratio(e_base, e_c[k]) >= D.thresholds(K, max(flags_v, 1))[1]
        table.append({"mechanism": m, "validation_z": zv, "validation_z_critical": zc,
                      "estimation_lr": lr, "estimation_lr_critical": lc, "p_value": D.p_value(zv),
                      "significant": bool(confirmed and lr >= lc and D.not_worse(yv, e_c[k], e_base)),
                      "val_mse": float(np.mean(e_c[k] ** 2)),
                      "val_reduction": float(1 - np.mean(e_c[k] ** 2) / np.mean(e_base ** 2)),
                      "mean_fit_percent": float(np.mean(fk)),
                      "fit_gain": float(np.mean(fk) - np.mean(base_fit)),
                      "parameters": M.physical_parameters(thc[k], m, lay, ts, extra), "k": k})
    # the tests decide what is significant; the size of the improvement (validation MSE) ranks
    ranked = sorted(table, key=lambda r: -r["val_reduction"] if np.isfinite(r["val_reduction"]) else np.inf)
    if "ambient_variation" in cands and amb is None and n > 1:
        # unmeasured surroundings are one temperature every zone sees: the zones' own drifts (the
        # per-zone fits) must agree, or the slow misfit the drift absorbs is something else
        loc["drift_agreement_z"] = D.common_drift_z(thc_own[cands.index("ambient_variation")][:, lay.sl("drift")])
        lrs = loc.get("drift_own_vs_common_lr")
        if not (D.common_drift(loc["drift_agreement_z"])
                or (lrs is not None and not D.drift_contradicted(lrs, n_knots))):
            forbidden = {**forbidden, "ambient_variation": "the zones' own fitted surroundings drifts do not "
                                                           "agree: not one surroundings signal"}
    flagged = [{"mechanism": r["mechanism"], "reason": forbidden[r["mechanism"]],
                "validation_z": r["validation_z"], "parameters": r["parameters"]}
               for r in ranked if r["significant"] and r["mechanism"] in forbidden]
    sig = [r for r in ranked if r["significant"] and r["mechanism"] not in forbidden]
    if "ambient_variation" in cands:
        # a slow body or a drift: the drift fitted on estimation follows the input-driven
        # (baseline-simulated) temperature through a lag only if it is a body (decide.py)
        # (and, unmeasured, the drift re-estimated on the validation record follows the baseline's
        # simulation of that record: a designed record can show it; the two records' tests are
        # combined, `bodydrift.combined_dependence`)
        kstep = round(M.DRIFT_SPACING / ts)
        dr = np.median(thc_own[cands.index("ambient_variation")][:, lay.sl("drift")], axis=0)
        z_e = BD.input_dependence(rec_e["Phi"] @ (dr - dr.mean()), yb_e.mean(axis=1), ts, kstep)
        dv = rec_v_fit[1 + cands.index("ambient_variation"), 2 * n:2 * n + kv]
        z_v = (BD.input_dependence(Phi_v @ (dv - dv.mean()), yhat_v[0].mean(axis=1), ts, kstep)
               if not measured_var else 0.0)
        loc["drift_input_dependence_records_z"] = [z_e, z_v]
        loc["drift_input_dependence_z"] = BD.combined_dependence(
            [z_e, z_v], [BD.dependence_testable(max(lengths) if lengths else T, kstep),
                         BD.dependence_testable(Tv, kstep) and not measured_var])
        sig = BD.order_body_drift(sig, loc["drift_input_dependence_z"])
        # and by parsimony: a drift re-fits the slow part on the validation record (`slowbody.py`)
        sig = order_by_parsimony(sig, e_c, cands, k_val, loc)
        # and on the estimation record, where both are charged every parameter (`decide.py`)
        sig = order_by_estimation(sig, res_c, cands, dof, loc)
    if sig:
        # a body slower than the record, tied with an identified one-parameter mechanism: the latter
        k0 = sig[0]["k"]
        sig = D.prefer_identified(sig, t_span, lambda r: D.is_rival(D.predictive_z(e_c[r["k"]], e_c[k0])),
                                  lambda m: M.n_added_per_zone(m, lay))
        # of the explanations the validation record leaves tied, the strongest on the estimation
        # record; a body the record does not identify is not moved ahead by it (its near-constant
        # heat term gains on the estimation record what `prefer_identified` just set aside)
        k0 = sig[0]["k"]
        sig = D.prefer_evidence(sig, lambda r: (D.promotable(r, t_span)
                                                and D.is_rival(D.predictive_z(e_c[r["k"]], e_c[k0]))),
                                lambda r: dof(r["mechanism"]))
    chosen, rivals, conf_top = [], [], 0.0
    aug_yhat, aug_theta = yhat_v[0], thb
    added, level_mode, aug = [], None, {}
    if sig:
        top = sig[0]
        kt = top["k"]
        slow = ("heat_accumulation", "ambient_variation")
        tied = top["mechanism"] in slow and BD.body_drift_tied([r["mechanism"] for r in sig],
                                                              loc.get("drift_input_dependence_z", 0.0))
        for r in sig[1:]:
            if (D.is_rival(D.predictive_z(e_c[r["k"]], e_c[kt]))
                    or (tied and r["mechanism"] in slow)):
                rivals.append(r["mechanism"])
        others = [r for r in ranked if r is not top and r["val_reduction"] > 0]
        run = BD.confidence_runner(top["mechanism"], [r["mechanism"] for r in others], measured_var)
        # the top against another candidate on the estimation record, charged what it adds beyond it
        z_est = lambda r: D.predictive_z(res_c[r["k"]], res_c[kt], dof(top["mechanism"]) - dof(r["mechanism"]))
        z_run, z_run_est = None, None
        if run is not None:
            z_run, z_run_est = D.predictive_z(e_c[others[run]["k"]], e_c[kt]), z_est(others[run])
            loc["runner"] = {"mechanism": others[run]["mechanism"], "validation_z": z_run,
                             "estimation_z": z_run_est}
        conf_top = D.confidence(top["validation_z"], z_run, z_run_est)
        other_slow = next((r for r in table if r["mechanism"] in slow and r is not top
                           and r["mechanism"] not in forbidden), None)
        if other_slow is not None and not measured_var:
            # a body or a drift: only the drift's input dependence separates them (decide.py)
            z_in = loc.get("drift_input_dependence_z", 0.0)
            fits = other_slow["estimation_lr"] >= other_slow["estimation_lr_critical"]
            if BD.slow_rival(top["mechanism"], fits, z_in):
                rivals += [other_slow["mechanism"]] if other_slow["mechanism"] not in rivals else []
            if top["mechanism"] in slow and fits:
                conf_top = min(conf_top, (1.0 - D.p_value(top["validation_z"]))
                               * BD.slow_order_confidence(top["mechanism"], z_in))
        if D.uncertain(conf_top):
            # not a confident name: every candidate that improved on the baseline and that the
            # top one does not beat, on the validation record or on the estimation one, is a
            # rival, significant alone or not
            rivals += [r["mechanism"] for r in others if r["mechanism"] not in rivals + [top["mechanism"]]
                       and (D.is_rival(D.predictive_z(e_c[r["k"]], e_c[kt])) or D.is_rival(z_est(r)))]
        chosen = [top["mechanism"]]
        # ---- 6. the combination, fitted jointly over all zones, grown forward by the tests ------
        # every candidate may join (one that helps only beside another, e.g. radiation once the
        # surroundings sit at their level, or a coupling behind a lag), each addition judged
        # given the others by both tests against the smaller joint model
        pool = [r["mechanism"] for r in ranked if r is not top and r["mechanism"] not in forbidden
                and (P or irregular or r["mechanism"] != "recoat_cooling")]
        js = JointFits(n=n, lay=lay, y=y, yv=yv, sh=sh_e, ev=ev_e, delay=best_delay,
                        measured=amb is not None, measured_var=measured_var, level=level,
                        neutral=joint_start(y, u, ts, level if amb is not None else float(y[0].mean()), lay),
                        u_pad_v=rec_v["u_pad"], uv=rec_v["u"],
                        n_iter=JOINT_ITER, slots=1 + (amb is None) + len(pool), val_slots=K + 1,
                        n_active=joint_active(n, lay, chosen[0], pool))
        if js.n_active > RESTRICT_ABOVE:
            # a wide model: each zone's strongest couplings only, additions restricted
            js.keep, js.neutral = pruned_start(js.neutral, lay, u, y, thc[cands.index("lateral_conduction")]
                                               if "lateral_conduction" in cands else None)
            js.n_active = joint_active(n, lay, chosen[0], pool, js.keep)
            js.n_active_add = restricted_active(n, lay, pool, js.keep)
        aug, added, chosen = forward_select(js, validate, k_val, chosen[0], pool, fit_of)
        if not D.not_worse(yv, aug["e"], e_c[kt]):
            # the joint structure predicts the validation record worse than the top mechanism's
            # own (per-zone) model: that model is reported, with its mechanism alone
            aug = {"theta": thc[kt], "yhat": yhat_v[kt + 1], "level_mode": None, "level_test": None,
                   "fit": "per zone (the joint fit predicted the validation record worse)"}
            chosen = [top["mechanism"]]
        aug_theta, aug_yhat, level_mode = aug["theta"], aug["yhat"], aug["level_mode"]
    tick({"stage": "combination"})

    e_aug = yv - aug_yhat
    aug_fit = fit_of(e_aug)
    noise = D.sensor_noise(e_aug)
    findings = []
    for rank, mech in enumerate(chosen):
        row = next(r for r in table if r["mechanism"] == mech)
        dz = np.mean(e_base ** 2, axis=0) - np.mean(e_c[row["k"]] ** 2, axis=0)
        zones = [i + 1 for i in range(n) if dz[i] >= 0.5 * dz.max()] if dz.max() > 0 else list(range(1, n + 1))
        params = M.physical_parameters(aug_theta, mech, lay, ts, extra)
        if rank == 0:
            conf, mech_rivals = conf_top, rivals
            effect = D.rms(yhat_v[0] - yhat_v[row["k"] + 1])
        else:
            # an addition tied with others of its round is named with them as its rivals
            acc = next(a for a in added if a["accepted"] and a["mechanisms"][-1] == mech)
            tie = rivals_among(acc.get("z_over", {}), chosen)
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
                    "runner_up": next((r["mechanism"] for r in ranked if r["mechanism"] != mech), None),
                    "zone_mse_reduction": [round(float(v), 5) for v in dz],
                    "effect_rms_C": round(effect, 4), "sensor_noise_C": round(noise, 4)}
        if lengths:     # each pooled record's share of the estimation evidence (`pool.py`)
            evidence["records"] = PL.evidence_shares(R_e, res_c[row["k"]], lengths)
        evidence.update(mechanism_evidence(mech, loc, per_ev, drops if irregular else None))
        findings.append({"mechanism": mech, "confidence": float(conf), "zones": zones,
                         "summary": summary(mech, zones, params, D.uncertain(conf), mech_rivals,
                                            (effect, noise) if small else None),
                         "below_noise": small,
                         "evidence": evidence,
                         "parameters": params, "rivals": mech_rivals,
                         "uncertain": bool(D.uncertain(conf))})
    sae = lambda e: float(np.sum(np.abs(e))) if np.all(np.isfinite(e)) else float("nan")
    result = {
        "verdict": "mismatch" if findings else "no_significant_mismatch",
        "decision": {"test": "whitened likelihood ratio (estimation) and Diebold-Mariano (validation)",
                     "family_false_alarm_rate": D.ALPHA, "candidates_tested": K},
        "baseline": {"model": "greybox (isolated zones, full heater gains, constant surroundings)",
                     "mean_fit_percent": float(np.mean(base_fit)),
                     "fit_percent": [float(v) for v in base_fit], "sum_abs_error": sae(e_base)},
        "findings": findings,
        "flagged": flagged,
        "inputs_left_out": [f"u_{nm}" for nm in dropped],
        "estimation_records": [{"samples": d.n_samples, "duration_s": d.n_samples * ts} for d in records],
        "augmented": {"mechanisms": list(chosen),
                      "fit": aug.get("fit", "joint (all zones, coupled simulation error)") if chosen
                      else "baseline",
                      "surroundings": level_mode,
                      "surroundings_test": aug.get("level_test") if chosen else None,
                      "mean_fit_percent": float(np.mean(aug_fit)),
                      "fit_percent": [float(v) for v in aug_fit], "sum_abs_error": sae(e_aug),
                      "parameters": {m: M.physical_parameters(aug_theta, m, lay, ts, extra)
                                     for m in chosen}},
        "localisation": loc,
        "candidates": [{k: (round(v, 6) if isinstance(v, float) else v) for k, v in r.items()
                        if k != "k"} for r in ranked],
        "combinations": added,
        "seconds": time.perf_counter() - t_start,
    }
    # arrays for the report (not JSON): dropped by `to_json`
    result["_arrays"] = {"yhat_baseline": yhat_v[0], "yhat_augmented": aug_yhat, "resid_est": R_e,
                         "resid_est_candidates": {m: res_c[k] for k, m in enumerate(cands)},
                         "resid_val": {"baseline": e_base, **{m: e_c[k] for k, m in enumerate(cands)}},
                         "k_val": {m: k_val((m,)) for m in cands}}
    # the fitted single-mechanism models and what simulating them needs (`experiment.py`)
    result["_models"] = {"theta": {"baseline": thb, **{m: thc[k] for k, m in enumerate(cands)}},
                         "layout": lay, "level": level, "ts_free": ts_free, "t_ref": t_ref,
                         "delay": best_delay, "measured_ambient": measured_var, "period": P,
                         "zone_phase": per_ev.get("zone_phase"), "inputs_left_out": dropped}
    tick({"stage": "done"})
    return result


def to_json(result: dict) -> dict:
    """The result without its report arrays (keys starting with `_`)."""
    return {k: v for k, v in result.items() if not k.startswith("_")}


__all__ = ["diagnose", "to_json"]

