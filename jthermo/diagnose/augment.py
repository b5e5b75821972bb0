"""The combination stage of a diagnosis: the augmented model fitted jointly over all zones and
grown by forward selection (`joint.forward_select`).

The top mechanism is refitted *jointly* over all zones (coupled simulation error: zones interact
through their simulated temperatures and the fitted exchange), with the surroundings at the
record's rest level (its first sample: the heaters were off before it) unless both tests demand
a fitted level, and grown by forward selection (up to `joint.MAX_COMBINED` mechanisms): every
other candidate may join, significant alone or not (radiation shows only once the surroundings
sit at their level, a coupling only behind a lag); an addition is kept only if it passes both
tests against the smaller joint model. Where the joint structure predicts the validation record
worse than the top mechanism's own per-zone model, that model is reported, alone.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import decide as D
from .candidates import Candidates
from .joint import (
    JointFits,
    forward_select,
    joint_active,
    joint_start,
    pruned_start,
    restricted_active,
)
from .prepare import Baseline, Localisation, Problem
from .ranking import Ranking, TopFinding
from .validation import Validation


@dataclasses.dataclass(frozen=True)
class Augmented:
    """The augmented model: its mechanisms, parameters and validation prediction."""
    chosen: list            # its mechanisms, the top first
    theta: np.ndarray       # (n, P)
    yhat: np.ndarray        # (Tv, n) its validation prediction, °C
    level_mode: str | None  # the surroundings: measured, rest or fitted (None: per zone)
    added: list             # every combination tried
    fit: dict               # `joint.forward_select`'s model (empty: nothing significant)


def baseline_only(base: Baseline, vl: Validation) -> Augmented:
    """Nothing significant: the baseline."""
    return Augmented(chosen=[], theta=base.theta, yhat=vl.yhat[0], level_mode=None, added=[], fit={})


def combine(pb: Problem, locn: Localisation, cands: Candidates, vl: Validation, rk: Ranking, top: TopFinding,
            joint_iter: int, restrict_above: int) -> Augmented:
    """The joint fit of `top`'s mechanism grown by forward selection over the other candidates
    (the recoat one only where events were found); `joint_iter` Levenberg–Marquardt iterations
    per joint fit; a model wider than `restrict_above` Jacobian columns is pruned and fits its
    additions restricted (`joint.py`)."""
    n, lay, y, u, ts = pb.n, pb.lay, pb.y, pb.u, pb.ts
    names = list(cands.names)
    first, kt = top.row["mechanism"], top.row["k"]
    pool = [r["mechanism"] for r in rk.ranked if r is not top.row and r["mechanism"] not in rk.forbidden
            and (locn.period or locn.irregular or r["mechanism"] != "recoat_cooling")]
    vd = vl.validator
    js = JointFits(n=n, lay=lay, y=y, yv=vd.yv, sh=pb.sh_e, ev=locn.events, delay=locn.delay,
                   measured=pb.amb is not None, measured_var=pb.measured_var, level=pb.level,
                   neutral=joint_start(y, u, ts, pb.level if pb.amb is not None else float(y[0].mean()), lay),
                   u_pad_v=pb.rec_v.u_pad, uv=pb.rec_v.u,
                   n_iter=joint_iter, slots=1 + (pb.amb is None) + len(pool), val_slots=cands.K + 1,
                   n_active=joint_active(n, lay, first, pool))
    if js.n_active > restrict_above:
        # a wide model: each zone's strongest couplings only, additions restricted
        js.keep, js.neutral = pruned_start(js.neutral, lay, u, y, cands.theta[names.index("lateral_conduction")]
                                           if "lateral_conduction" in names else None)
        js.n_active = joint_active(n, lay, first, pool, js.keep)
        js.n_active_add = restricted_active(n, lay, pool, js.keep)
    aug, added, chosen = forward_select(js, vd, vd.k_val, first, pool, vd.fit_of)
    if not D.not_worse(vd.yv, aug["e"], vl.e_c[kt]):
        # the joint structure predicts the validation record worse than the top mechanism's
        # own (per-zone) model: that model is reported, with its mechanism alone
        aug = {"theta": cands.theta[kt], "yhat": vl.yhat[kt + 1], "level_mode": None, "level_test": None,
               "fit": "per zone (the joint fit predicted the validation record worse)"}
        chosen = [first]
    return Augmented(chosen=list(chosen), theta=aug["theta"], yhat=aug["yhat"], level_mode=aug["level_mode"],
                     added=added, fit=aug)


__all__ = ["Augmented", "baseline_only", "combine"]
