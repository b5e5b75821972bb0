"""Checks of the records handed to the diagnosis, and the inputs it leaves out."""

from __future__ import annotations

import numpy as np

from ..data import idle_inputs, keep_inputs, require_output_variation
from ..errors import DataError


def check_records(est, val, ts_tolerance: float) -> None:
    """Refuse records the diagnosis cannot use, with a one-line reason (`DataError`)."""
    for nm, d in (("estimation", est), ("validation", val)):
        if not hasattr(d, "y") or not hasattr(d, "u"):
            raise DataError(f"diagnose: the {nm} data must be IOData")
    if est.n_outputs != val.n_outputs or est.n_inputs != val.n_inputs:
        raise DataError(f"diagnose: estimation ({est.n_inputs} inputs, {est.n_outputs} outputs) and "
                        f"validation ({val.n_inputs}, {val.n_outputs}) data do not match")
    # logged runs of one device differ in their mean step by a fraction of a percent (clock
    # jitter): the validation record is simulated at the estimation record's sample time
    if abs(est.ts - val.ts) > ts_tolerance * est.ts:
        raise DataError(f"diagnose: sample times differ: {est.ts:g} s and {val.ts:g} s")
    _n, nu = est.n_outputs, est.n_inputs
    need = 10 * (3 + nu)
    for nm, d in (("estimation", est), ("validation", val)):
        if d.n_samples < need:
            raise DataError(f"diagnose: the {nm} data have {d.n_samples} samples; at least {need} "
                            "are needed")
    if np.any(np.std(est.u, axis=0) < 1e-9):
        j = int(np.argmin(np.std(est.u, axis=0)))
        raise DataError(f"diagnose: input `u_{est.input_names[j]}` is constant in the estimation "
                        "data and cannot excite the system")
    for nm, d in (("estimation", est), ("validation", val)):
        require_output_variation(d, f"diagnose: the {nm} data")
    if np.any(est.u < -1e-9) and "power" not in " ".join(est.notes):
        pass  # inputs are power fractions on the printer; other systems may differ: no check


def drop_idle_inputs(est, val):
    """Leave out inputs that are constant in both records (a logged, unused heater): their
    effect cannot be told from the surroundings level, and they change nothing in either."""
    if not all(hasattr(d, "u") for d in (est, val)) or est.n_inputs != val.n_inputs or est.n_inputs < 2:
        return est, val, []
    idle = [j for j in sorted(set(idle_inputs(est)) & set(idle_inputs(val)))
            if abs(float(est.u[0, j]) - float(val.u[0, j])) < 1e-9]
    if not idle or len(idle) == est.n_inputs:
        return est, val, []
    keep = [n for j, n in enumerate(est.input_names) if j not in idle]
    return keep_inputs(est, keep), keep_inputs(val, keep), [est.input_names[j] for j in idle]


__all__ = ["check_records", "drop_idle_inputs"]
