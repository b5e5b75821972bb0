"""Where a diagnosis's recoat candidate places its drops, on the estimation and the validation record.

Two detections find recoat drops in the baseline's residuals: at a fixed period
(`localise.detect_periodic`, each zone its own phase) and at any times (`events.detect_drops`).
On the estimation record the drops at any times replace the periodic events where they
explain more of the residuals (`events.step_gain`: steps recovering at the baseline's loss
rates); on the validation record the same kind is found again on its own residuals: the
period kept and the phases re-estimated, or the drops detected afresh, their flags charged as
parameters fitted on that record.
"""

from __future__ import annotations

import numpy as np

from .events import detect_drops, flag_matrix, step_gain
from .localise import detect_periodic, event_matrix


def estimation_events(resid: np.ndarray, loss_rates: np.ndarray, ts: float, loc: dict) -> dict:
    """The recoat events of the estimation record from the baseline's residuals `resid (T, n)`
    and its loss rates `loss_rates (n,)` (1/s). Writes the searches' figures to `loc`
    (`periodic`, `drops`). Returns `{"events": (T, n) flags, "period": samples (0: none, or
    drops at any times), "irregular": bool, "periodic": detect_periodic's result, "drops":
    detect_drops's result}`."""
    T, n = resid.shape
    per = detect_periodic(resid, ts)
    loc["periodic"] = {k: per[k] for k in ("period_s", "statistic", "significant")}
    events, period = np.zeros((T, n)), 0
    if per["significant"]:
        period = per["period_s"] / ts          # samples, any fraction
        events = event_matrix(T, period, per["zone_phase"])
    drops = detect_drops(resid, ts)
    loc["drops"] = {k: drops[k] for k in ("significant", "statistic", "level", "rise")}
    loc["drops"]["events"] = len(drops["times_s"])
    irregular = False
    if drops["significant"]:
        ev_d = flag_matrix(T, drops["flags"])
        if not period or step_gain(resid, ev_d, loss_rates, ts) > step_gain(resid, events, loss_rates, ts):
            events, period, irregular = ev_d, 0, True
    loc["drops"]["used"] = irregular
    return {"events": events, "period": period, "irregular": irregular, "periodic": per, "drops": drops}


def validation_events(resid: np.ndarray, found: dict, ts: float, loc: dict) -> tuple[np.ndarray, int]:
    """The recoat events of the validation record from its baseline residuals `resid (Tv, n)`,
    of the kind `estimation_events` `found`: `(events (Tv, n), flags charged as parameters
    fitted on the record)`."""
    Tv, n = resid.shape
    if found["period"]:
        dv = detect_periodic(resid, ts, period_range=(found["period"] * ts,) * 2)
        return event_matrix(Tv, found["period"], dv["zone_phase"]), 0
    dv = detect_drops(resid, ts, min_events=1)
    loc["drops"]["validation_events"] = len(dv["times_s"])
    if dv["significant"]:
        return flag_matrix(Tv, dv["flags"]), dv["n_flags"]
    return np.zeros((Tv, n)), 0


__all__ = ["estimation_events", "validation_events"]
