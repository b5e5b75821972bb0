"""The validation stage of a diagnosis: every model simulated coupled on the validation record,
its initial states (and what each mechanism re-estimates) fitted there.

A model fitted per zone is simulated with all zones coupled (neighbours simulated), from the
validation record's first sample, with only the initial states re-estimated, and the
surroundings level where it is not measured (for every model alike), a body's state for
`heat_accumulation` and the unmeasured drift's knots for `ambient_variation`: each charged as
parameters fitted on that record (`Validator.k_val`). Recoat events are found again on the
validation record's own residuals (`recoat.validation_events`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from . import mechanisms as M
from .candidates import Candidates
from .fitting import fit_records
from .prepare import Baseline, Localisation, Problem
from .recoat import validation_events
from .stages import fit_percent, shared, simulate_baseline


@dataclasses.dataclass(frozen=True)
class Validator:
    """Simulations of models on the validation record (`__call__`) and what they re-estimate there."""
    lay: M.Layout
    yv: np.ndarray          # (Tv, n) °C
    kv: int                 # drift knots of the validation record
    sh_v: dict              # the simulator's record-wide inputs of the validation record
    events: np.ndarray      # (Tv, n) recoat event flags
    flags: int              # recoat flags fitted on the record
    level: float            # °C
    ts_free: float
    u_pad: np.ndarray       # (nu,)
    delay: float            # samples
    measured_var: bool

    @property
    def n(self) -> int:
        return self.yv.shape[1]

    def __call__(self, models, with_rec=False):
        """Coupled simulations `(M, Tv, n)` of models on the validation record: (θ, mechanism set)
        pairs fitted per zone (surroundings as the baseline's), or (θ, set, setup) for the joint
        fits (`JointFits.setup` of the validation record); `with_rec`: also the record parameters
        re-estimated on it `(M, 2 n + kv + 1)` (initial states, body states, drift knots, level)."""
        n, kv, lay, yv = self.n, self.kv, self.lay, self.yv
        Mn = len(models)
        R = 2 * n + kv + 1              # + the record's own surroundings level (when not measured)
        rec0, rmask = np.zeros((Mn, R)), np.zeros((Mn, R))
        per_zone = {"ts_level": self.level, "ts_free": self.ts_free, "u_pad": self.u_pad}
        setups = [m[2] if len(m) == 3 else per_zone for m in models]
        lev_m = np.array([su["ts_level"] for su in setups])
        free_m = np.array([su["ts_free"] for su in setups])
        for j, (m, _su) in enumerate(zip(models, setups)):
            th, st = m[0], m[1]
            rec0[j, :n] = yv[0]
            _, gam = M.wall_parameters(th[:, lay.sl("log_tauw")][:, 0], th[:, lay.sl("log_gamma")][:, 0])
            tsl = lev_m[j] + free_m[j] * float(np.median(th[:, lay.sl("ts0")][:, 0]))
            rec0[j, n:2 * n] = tsl + (rec0[j, :n].mean() - tsl) / (1.0 + gam)
            rmask[j, :n] = 1.0
            rmask[j, n:2 * n] = float("heat_accumulation" in st)
            rmask[j, 2 * n:2 * n + kv] = float("ambient_variation" in st and not self.measured_var)
            rmask[j, -1] = free_m[j]
        fper = {"events": jnp.asarray(np.stack([self.events] * Mn)),
                "delay": jnp.asarray(np.array([self.delay if "input_delay" in m[1] else 0.0
                                               for m in models])),
                **{k: jnp.asarray(np.stack([su[k] for su in setups], dtype=float)) for k in per_zone}}
        rec_fit, yh, _ = fit_records(jnp.asarray(np.stack([m[0] for m in models])),
                                     jnp.asarray(np.stack([M.on_vector(m[1]) for m in models])),
                                     jnp.asarray(rec0), jnp.asarray(rmask), jnp.asarray(yv), fper, self.sh_v,
                                     lay, 10)
        return (np.asarray(yh), np.asarray(rec_fit)) if with_rec else np.asarray(yh)

    def k_val(self, st) -> int:
        """Parameters re-estimated on the validation record beyond the zones' initial states."""
        return (self.n * ("heat_accumulation" in st) + self.kv * ("ambient_variation" in st and not self.measured_var)
                + self.flags * ("recoat_cooling" in st))

    def fit_of(self, e) -> np.ndarray:
        """Simulation fit % per zone of validation residuals `e (Tv, n)` (NaN if any is not finite)."""
        return fit_percent(self.yv, self.yv - e) if np.all(np.isfinite(e)) else np.full(self.n, np.nan)


@dataclasses.dataclass(frozen=True)
class Validation:
    """The baseline's and every candidate's predictions of the validation record."""
    validator: Validator
    yhat: np.ndarray        # (K + 1, Tv, n): the baseline's, then each candidate's
    rec_fit: np.ndarray     # (K + 1, 2 n + kv + 1) the record parameters re-estimated there
    Phi: np.ndarray         # (Tv, kv) its drift basis
    e_base: np.ndarray      # (Tv, n) the baseline's residuals
    e_c: tuple              # each candidate's residuals (Tv, n)

    @property
    def Tv(self) -> int:
        return self.e_base.shape[0]


def validate_candidates(pb: Problem, base: Baseline, locn: Localisation, cands: Candidates) -> Validation:
    """The `Validator` of the validation record and the baseline's and candidates' predictions."""
    lay, n, ts = pb.lay, pb.n, pb.ts
    Tv = pb.val.n_samples
    yv = np.asarray(pb.val.y, float)
    kv = M.n_drift_knots(Tv, ts)
    Phi_v = M.drift_basis(Tv, ts, kv)
    sh_v = shared(dataclasses.replace(pb.rec_v, Phi=Phi_v, u_pads=None), pb.level, pb.ts_free, ts, pb.t_ref)
    # recoat events on the validation record, found again on its own residuals (`recoat.py`)
    ev_v, flags_v = np.zeros((Tv, n)), 0
    if locn.period or locn.irregular:
        thb_v = base.theta.copy()
        thb_v[:, lay.sl("x0")] = yv[0][:, None]
        ybv = simulate_baseline(thb_v, pb.rec_v, ts, pb.level, pb.ts_free, lay)
        ev_v, flags_v = validation_events(yv - ybv, locn.recoat, ts, locn.report)
    vd = Validator(lay=lay, yv=yv, kv=kv, sh_v=sh_v, events=ev_v, flags=flags_v, level=pb.level,
                   ts_free=pb.ts_free, u_pad=pb.rec_v.u_pad, delay=locn.delay, measured_var=pb.measured_var)
    yhat_v, rec_v_fit = vd([(base.theta, ())] + [(cands.theta[k], (m,)) for k, m in enumerate(cands.names)],
                           with_rec=True)
    return Validation(validator=vd, yhat=yhat_v, rec_fit=rec_v_fit, Phi=Phi_v, e_base=yv - yhat_v[0],
                      e_c=tuple(yv - yhat_v[k + 1] for k in range(cands.K)))


__all__ = ["Validation", "Validator", "validate_candidates"]
