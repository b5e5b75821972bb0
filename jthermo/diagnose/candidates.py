"""The candidate stage of a diagnosis: one augmented model per mechanism, fitted per zone on the
estimation record(s).

Zone i's model sees its neighbours' and the bed's measured temperatures (series-parallel form),
so all zones and candidates are independent small problems solved by the compiled masked
Levenberg–Marquardt (`fitting.fit_zones`, `ZoneFits`). Mechanism parameters start at their
neutral values (the baseline's kept); a stored-heat body also from slow starts and radiation
from steeper shares (`starts.py`), and the body from the fitted drift restricted to its form
(`slowbody.py`), each zone keeping its best. Where the surroundings are not measured,
`ambient_variation` is refitted with one drift for all zones (`commondrift.common_drift_fit`);
the zones' own drifts are kept (`Candidates.theta_own`) for the tests of agreement and input
dependence.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from . import decide as D
from . import mechanisms as M
from . import starts as ST
from .commondrift import common_drift_fit
from .fitting import fit_zones, sim_zones, still_falling
from .prepare import Baseline, Localisation, Problem
from .slowbody import refit_body_from_drift
from .stages import problems, record_starts


@dataclasses.dataclass(frozen=True)
class ZoneFits:
    """The per-zone fits of mechanism sets on the estimation record(s) (`__call__`)."""
    pb: Problem
    events: np.ndarray      # (T, n) recoat event flags
    delay: float            # samples: the dead time of sets with `input_delay`
    n_iter: int             # Levenberg–Marquardt iterations of a round
    rounds: int             # at most this many more rounds for the fits still falling at the cap

    def __call__(self, sets, starts, n_act=None, iters=None):
        """One augmented model per mechanism set, from `starts (S, n, P)`: (θ `(S, n, P)`,
        residuals `(S, T, n)`); `n_act` (static) the most free parameters of one problem
        (default: the sets' own), `iters` the iterations (default `n_iter`)."""
        pb, lay, n, T = self.pb, self.pb.lay, self.pb.n, self.pb.T
        S = len(sets)
        masks = np.concatenate([np.tile(np.minimum(pb.base_mask + sum(lay.mask(M.MECH_PARAMS[m]) for m in st),
                                                   1.0), (n, 1)) for st in sets])
        ons = jnp.asarray(np.concatenate([np.tile(M.on_vector(st), (n, 1)) for st in sets]))
        per_s = problems(pb.rec_e, S, events=np.stack([self.events] * S),
                         delays=[self.delay if "input_delay" in st else 0.0 for st in sets])
        if n_act is None:
            n_act = 4 * math.ceil(masks.sum(axis=1).max() / 4)      # fewer distinct compilations
        its, masks = self.n_iter if iters is None else iters, jnp.asarray(masks)
        th, _, hist = fit_zones(jnp.asarray(starts.reshape(S * n, -1)), masks, ons, per_s, pb.sh_e, lay, its,
                                n_act)
        for _ in range(self.rounds):       # fits still falling at the cap go on (`fitting.py`)
            more = still_falling(hist, T)
            if not more.any():
                break
            th, _, hist = fit_zones(th, masks, ons, per_s, pb.sh_e, lay, its, n_act, more * its)
        ys = np.asarray(sim_zones(th, ons, per_s, pb.sh_e, lay)).reshape(S, n, T).transpose(0, 2, 1)
        return np.asarray(th).reshape(S, n, -1), pb.y[None] - ys


@dataclasses.dataclass(frozen=True)
class Candidates:
    """The single-mechanism fits, in the order of `names`."""
    names: tuple            # the mechanisms
    theta: np.ndarray       # (K, n, P)
    resid: np.ndarray       # (K, T, n) estimation residuals
    theta_own: np.ndarray   # (K, n, P) before the common drift: each zone its own

    @property
    def K(self) -> int:
        return len(self.names)

    def index(self, mech: str) -> int:
        return self.names.index(mech)


def neutral_starts(pb: Problem, base: Baseline) -> np.ndarray:
    """Starts `(n, P)` with the baseline's parameters and every mechanism at its neutral value."""
    lay, thb, y = pb.lay, base.theta, pb.y
    neutral = np.stack([M.initial_theta(lay, log_a=thb[i, lay.sl("log_a")][0],
                                        log_b=thb[i, lay.sl("log_b")], x0=thb[i, lay.sl("x0")][0],
                                        ts0=thb[i, lay.sl("ts0")][0],
                                        xw0=(y[0].mean() - pb.level - thb[i, lay.sl("ts0")][0]) / 2.0)
                        for i in range(pb.n)])
    neutral = record_starts(neutral, y, pb.level, pb.lengths, lay)
    for grp in ("x0_rec", "ts0_rec"):          # pooled records: each its own, as the baseline's
        neutral[:, lay.sl(grp)] = thb[:, lay.sl(grp)]
    return neutral


def fit_candidates(pb: Problem, base: Baseline, locn: Localisation, fits: ZoneFits, body_iter: int,
                   drift_iter: int) -> Candidates:
    """Every mechanism of `pb.mechanisms` fitted per zone (`fits`), from the neutral start and
    the extra starts; the body's refit from the drift runs `body_iter` iterations, the common
    drift's at most `drift_iter` (and `fits.rounds` more rounds). Writes the zones' own against
    the common drift's likelihood ratios to the localisation report."""
    cands = list(pb.mechanisms)
    K, lay, n = len(cands), pb.lay, pb.n
    neutral = neutral_starts(pb, base)
    # a stored-heat body also from slow starts (`starts.body_starts`), radiation from steeper
    # shares (`starts.rad_starts`), each zone its best (its smallest estimation cost)
    extra_starts = {m: f(neutral, lay) for m, f in (("heat_accumulation", ST.body_starts),
                                                    ("radiative_loss", ST.rad_starts)) if m in cands}
    thc, res_c = fits([(m,) for m in cands] + [(m,) for m, st in extra_starts.items() for _ in st],
                      np.stack([neutral] * K + [t for st in extra_starts.values() for t in st]))
    for m, st in extra_starts.items():   # each call drops its extra fits: the next group's are at K
        thc, res_c = ST.best_of_starts(thc, res_c, cands.index(m), range(K, K + len(st)))
    # and from the fitted drift restricted to a body's form (`slowbody.body_from_drift`)
    thc, res_c = refit_body_from_drift(thc, res_c, cands, fits, pb.rec_e, pb.level, pb.ts_free, pb.ts, lay,
                                       body_iter)
    thc_own = thc
    if "ambient_variation" in cands and pb.amb is None and n > 1:
        # unmeasured surroundings: one drift for every zone; the zones' own drifts are kept for
        # the tests of agreement and input dependence. Where a surroundings column is measured
        # (constant), the per-zone drifts stay: there an estimated drift contradicts the
        # measurement, and the common one outranked a shared body in the in-class study
        # (`accumulation`, 6 zones)
        ka = cands.index("ambient_variation")
        thc, res_c = np.array(thc), np.array(res_c)
        res_own = res_c[ka].copy()
        thc[ka], res_c[ka] = common_drift_fit(thc[ka], pb.y, pb.sh_e, pb.level, pb.ts_free, lay, drift_iter,
                                              fits.rounds)
        locn.report["drift_own_vs_common_lr"] = [D.likelihood_ratio(res_c[ka][:, i:i + 1], res_own[:, i:i + 1])
                                                 for i in range(n)]
    return Candidates(names=tuple(cands), theta=thc, resid=res_c, theta_own=thc_own)


__all__ = ["Candidates", "ZoneFits", "fit_candidates", "neutral_starts"]
