"""The first stages of a diagnosis: the problem, the baseline, the localisation.

`prepare` reads the records once into a `Problem` (arrays, the surroundings, the layout, the
starts), which every later stage reads and none changes; `fit_baseline_stage` fits the
first-order baseline (`Baseline`); `localise_stage` locates its residuals, finds recoat events
and scans the dead time (`Localisation`). The localisation report (`report`, JSON-ready) is
the one dict the later stages write their figures to.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..models.greybox import first_order_start
from . import mechanisms as M
from . import pool as PL
from .joint import grid_start
from .localise import localise
from .recoat import estimation_events
from .stages import (
    RecordArrays,
    ambient_column,
    delayed_inputs,
    fit_baseline,
    record_arrays,
    record_starts,
    shared,
    simulate_baseline,
)


@dataclasses.dataclass(frozen=True)
class Problem:
    """One diagnosis's records as its fits see them."""
    records: tuple              # the estimation records (one, or several pooled)
    est: object                 # IOData: the estimation record(s), concatenated in time
    val: object                 # IOData: the validation record
    mechanisms: tuple           # the candidates tried
    ts: float                   # s
    y: np.ndarray               # (T, n) °C
    u: np.ndarray               # (T, nu)
    lengths: tuple              # pooled records' samples; () for one record
    amb: int | None             # the measured surroundings column, if both records have one
    level: float                # °C: the surroundings' (mean measured, else first-order estimate)
    ts_free: float              # 1.0 where the surroundings level is fitted (not measured)
    measured_var: bool          # the measured surroundings vary (> 0.05 °C)
    w_range: float              # °C: their range over both records
    n_knots: int                # drift knots of the estimation record(s)
    lay: M.Layout
    t_span: float               # s: the longest estimation record (what identifies a slow body)
    rec_e: RecordArrays
    rec_v: RecordArrays
    t_ref: float                # °C: where the radiative share is defined
    sh_e: dict                  # the simulator's record-wide inputs of the estimation record(s)
    base_mask: np.ndarray       # (P,) the baseline's free parameters
    th0: np.ndarray             # (n, P) the baseline's start

    @property
    def n(self) -> int:
        return self.y.shape[1]

    @property
    def T(self) -> int:
        return self.y.shape[0]

    def dof(self, mech: str) -> int:
        """The tests' degrees of freedom of `mech` (one drift for every zone where the
        surroundings are not measured)."""
        return M.n_added(mech, self.lay, shared_drift=self.amb is None)


def prepare(records, est, val, mechanisms) -> Problem:
    """The `Problem` of checked records (`checks.pool_records`): `records` the estimation
    records, `est` their concatenation, `val` the validation record."""
    lengths = tuple(d.n_samples for d in records) if len(records) > 1 else ()
    ts = float(est.ts)
    y, u = np.asarray(est.y, float), np.asarray(est.u, float)
    T, n = y.shape
    amb = ambient_column(est)
    if amb is not None and ambient_column(val) is None:
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
    _loss, _gain, surr = first_order_start(y, u, None if amb is None else np.full((T, 1), level), ts, 1.0)
    if level is None:
        level = surr
    n_knots = PL.drift_basis(lengths, ts)[0].shape[1] if lengths else M.n_drift_knots(T, ts)
    lay = M.make_layout(n, u.shape[1], n_knots, lengths)
    # the longest record: what identifies a slow body's time constant (pooled records are not
    # one long record)
    t_span = (max(lengths) if lengths else T) * ts
    rec_e = record_arrays(est, amb, level, n_knots, lengths)
    rec_v = record_arrays(val, amb, level, M.n_drift_knots(val.n_samples, ts))
    if not measured_var:
        rec_e = dataclasses.replace(rec_e, wdev=np.zeros_like(rec_e.wdev))
        rec_v = dataclasses.replace(rec_v, wdev=np.zeros_like(rec_v.wdev))
    t_ref = float(y.mean())
    base_names = ["log_a", "log_b", "x0", "x0_rec"] + (["ts0", "ts0_rec"] if ts_free else [])
    ga, gb, gx, gs = grid_start(y, u, ts, level, ts_free)
    th0 = np.stack([M.initial_theta(lay, log_a=ga[i], log_b=np.log(gb[i]), x0=gx[i], ts0=gs[i],
                                    xw0=(y[0].mean() - level) / 2.0)
                    for i in range(n)])
    return Problem(records=tuple(records), est=est, val=val, mechanisms=tuple(mechanisms), ts=ts, y=y, u=u,
                   lengths=lengths, amb=amb, level=level, ts_free=ts_free, measured_var=measured_var,
                   w_range=w_range, n_knots=n_knots, lay=lay, t_span=t_span, rec_e=rec_e, rec_v=rec_v,
                   t_ref=t_ref, sh_e=shared(rec_e, level, ts_free, ts, t_ref), base_mask=lay.mask(base_names),
                   th0=record_starts(th0, y, level, lengths, lay))


@dataclasses.dataclass(frozen=True)
class Baseline:
    """The baseline fitted on the estimation record(s)."""
    theta: np.ndarray       # (n, P)
    yhat: np.ndarray        # (T, n) its simulation, °C
    resid: np.ndarray       # (T, n) y - yhat


def fit_baseline_stage(pb: Problem) -> Baseline:
    """The first-order baseline (variable projection in NumPy, `baseline.py`)."""
    thb = fit_baseline(pb.th0, pb.y, pb.u, pb.ts, pb.level, pb.ts_free, pb.lay)
    yb = simulate_baseline(thb, pb.rec_e, pb.ts, pb.level, pb.ts_free, pb.lay)
    return Baseline(theta=thb, yhat=yb, resid=pb.y - yb)


def scan_delay(pb: Problem, theta: np.ndarray, dgrid: np.ndarray, refits: int) -> tuple:
    """The dead time (samples) on `dgrid` whose baseline simulation fits the estimation
    record(s) best: (best, the last scan's costs `(len(dgrid),)`, refits made).

    The baseline `theta` was fitted with no dead time, so its rates and gains have taken up part
    of one (a slower zone, a lagging response), and simulated with a delay it fits best short of
    the true one: by a sample for 4-9 zones of 16-24 s time constants and a 4-5 s delay, where
    the `input_delay` candidate, which moves within a sample of the scan's best, cannot reach the
    truth and a lamp lag out-fits it on both records. Each refit fits the baseline to the inputs
    delayed by the current best (`stages.delayed_inputs`: the profile of the fit over the dead
    time, at that point) and scans again with it, until the best stays."""
    def scan(th):
        return np.array([np.mean((pb.y - simulate_baseline(th, pb.rec_e, pb.ts, pb.level, pb.ts_free, pb.lay,
                                                           d)) ** 2) for d in dgrid])

    cost = scan(theta)
    best = float(dgrid[int(np.argmin(cost))])
    for k in range(refits):
        th = fit_baseline(pb.th0, pb.y, delayed_inputs(pb.rec_e, pb.lay, best), pb.ts, pb.level, pb.ts_free,
                          pb.lay)
        cost = scan(th)
        new = float(dgrid[int(np.argmin(cost))])
        if new == best:
            return best, cost, k + 1
        best = new
    return best, cost, refits


@dataclasses.dataclass(frozen=True)
class Localisation:
    """Where the baseline's residuals sit, the recoat events, the dead time."""
    report: dict            # JSON-ready figures; the later stages add theirs
    recoat: dict            # `recoat.estimation_events`' result
    events: np.ndarray      # (T, n) recoat event flags
    period: int             # samples between periodic recoats (0: none)
    irregular: bool         # recoats at any times
    periodic: dict
    drops: dict
    delay: float            # samples: the dead-time scan's best


def localise_stage(pb: Problem, base: Baseline, max_delay: int, max_delay_s: float,
                   delay_step: float, refits: int = 0) -> Localisation:
    """Localisation, recoat events (`recoat.py`) and the dead-time scan: the baseline simulated
    with each delay on a grid of `delay_step` samples up to `max_delay` samples (or
    `max_delay_s` seconds when that is more), then refitted with its inputs delayed by the
    scan's best and scanned again, up to `refits` times, until the best stays (`scan_delay`)."""
    loc = localise(base.resid, pb.y, pb.u, pb.ts)
    lay = pb.lay
    rc = estimation_events(base.resid, np.exp(base.theta[:, lay.sl("log_a")][:, 0]), pb.ts, loc)
    max_d = min(M.PAD - 3.0, max(float(max_delay), math.ceil(max_delay_s / pb.ts)))
    dgrid = np.arange(delay_step, max_d + 1e-9, delay_step)
    best_delay, dcost, n_refits = scan_delay(pb, base.theta, dgrid, refits)
    loc["delay_scan"] = {"delays_s": (dgrid * pb.ts).tolist(), "cost": dcost.round(6).tolist(),
                         "baseline_cost": float(np.mean(base.resid ** 2)), "refits": n_refits}
    return Localisation(report=loc, recoat=rc, events=rc["events"], period=rc["period"],
                        irregular=rc["irregular"], periodic=rc["periodic"], drops=rc["drops"], delay=best_delay)


__all__ = ["Baseline", "Localisation", "Problem", "fit_baseline_stage", "localise_stage", "prepare", "scan_delay"]
