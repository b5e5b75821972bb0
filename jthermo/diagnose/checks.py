"""Checks of the records handed to the diagnosis, and the inputs it leaves out."""

from __future__ import annotations

import numpy as np

from ..data import IOData, idle_inputs, keep_inputs, require_output_variation
from ..errors import DataError


def check_records(est, val, ts_tolerance: float, excitation: bool = True) -> None:
    """Refuse records the diagnosis cannot use, with a one-line reason (`DataError`);
    `excitation`: every input must vary in `est` (a pooled record may leave one constant
    that another record moves)."""
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
    if excitation and np.any(np.std(est.u, axis=0) < 1e-9):
        j = int(np.argmin(np.std(est.u, axis=0)))
        raise DataError(f"diagnose: input `u_{est.input_names[j]}` is constant in the estimation "
                        "data and cannot excite the system")
    for nm, d in (("estimation", est), ("validation", val)):
        if excitation or nm == "validation":
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


def as_records(est) -> list:
    """The estimation records handed to the diagnosis: one `IOData` or a sequence of them."""
    if isinstance(est, IOData):
        return [est]
    if isinstance(est, (list, tuple)) and est and all(isinstance(d, IOData) for d in est):
        return list(est)
    raise DataError("diagnose: the estimation data must be IOData or a non-empty list of IOData")


def concatenate(records) -> IOData:
    """Records of one plant (the same signals) one after another in time, at the first's
    sample time: what the pooled fits see (`pool.py` keeps the records' bounds)."""
    first = records[0]
    if len(records) == 1:
        return first
    return IOData(u=np.concatenate([np.asarray(d.u, float) for d in records]),
                  y=np.concatenate([np.asarray(d.y, float) for d in records]),
                  w=np.concatenate([np.asarray(d.w, float) for d in records]), ts=float(first.ts),
                  input_names=first.input_names, output_names=first.output_names,
                  signal_names=first.signal_names)


def pool_records(records, val, ts_tolerance: float):
    """Pooled estimation records of one plant: each checked against the first (the same input,
    output and signal names, the same sample time to `ts_tolerance`) and against `val`
    (`check_records`), inputs constant in every record and in `val` at one value left out
    (`drop_idle_inputs`). Returns (records, their concatenation in time, `val`, inputs left out)."""
    first = records[0]
    for j, d in enumerate(records[1:], start=2):
        for what in ("input_names", "output_names", "signal_names"):
            if getattr(d, what) != getattr(first, what):
                raise DataError(f"diagnose: estimation record {j} has other {what.split('_')[0]}s "
                                f"({', '.join(getattr(d, what)) or 'none'}) than record 1 "
                                f"({', '.join(getattr(first, what)) or 'none'}): not one plant's records")
        if abs(d.ts - first.ts) > ts_tolerance * first.ts:
            raise DataError(f"diagnose: sample times of the estimation records differ: {first.ts:g} s "
                            f"and {d.ts:g} s (record {j})")
    if len(records) == 1:
        est, val, dropped = drop_idle_inputs(first, val)
        return [est], est, val, dropped
    cat = concatenate(records)
    # an input constant over the concatenation is constant, at one value, in every record
    cat, val, dropped = drop_idle_inputs(cat, val)
    if dropped:
        records = [keep_inputs(d, cat.input_names) for d in records]
    for j, d in enumerate(records, start=1):
        try:
            check_records(d, val, ts_tolerance, excitation=False)
        except DataError as e:
            raise DataError(str(e).replace("the estimation data", f"estimation record {j}")) from None
    return records, cat, val, dropped


__all__ = ["as_records", "check_records", "concatenate", "drop_idle_inputs", "pool_records"]
