"""A logged time axis onto a uniform grid (`data.from_columns`): jitter, dropped samples, late
and displaced stamps repaired by linear interpolation and said so; anything else refused."""

from __future__ import annotations

import numpy as np

from .errors import DataError

#: jitter allowed in logged time stamps before re-gridding is refused (fraction of Ts)
JITTER_TOLERANCE = 0.2
#: longest gap (in samples) that re-gridding may bridge by interpolation
MAX_GAP_SAMPLES = 3


def uniform_time(t: np.ndarray, mat: np.ndarray, source: str, tol: float, row_offset: int = 0):
    """`(t, mat, notes)` on a uniform grid of the median step; `mat[:, 0]` is `t`, its other
    columns are interpolated. Rows in messages count samples from 1, plus `row_offset`."""
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        r = int(bad[0]) + 2 + row_offset
        kind = "duplicated" if dt[bad[0]] == 0 else "decreasing"
        raise DataError(f"{source}: time `t` is {kind} at row {r} (t={t[bad[0] + 1]:g})")
    step = float(np.median(dt))
    dev = np.abs(dt - step) / step
    if dev.max() <= 1e-6:
        n = len(t)
        t_uniform = t[0] + step * np.arange(n)
        return t_uniform, np.column_stack([t_uniform, mat[:, 1:]]), []
    # Jitter, dropped samples, late or displaced stamps: see `_off_grid`.
    ratio = dt / step
    whole = np.round(ratio)
    off = np.abs(ratio - whole)
    late, displaced, first_bad = _off_grid(ratio, tol)
    if first_bad is not None:
        i = first_bad
        raise DataError(
            f"{source}: time `t` is not uniform: step {dt[i]:g} s at row {i + 2 + row_offset} against a median "
            f"of {step:g} s (more than {tol:.0%} jitter off the sample grid that is not one late or "
            f"displaced stamp, or a gap over {MAX_GAP_SAMPLES} samples)")
    n = int(round((t[-1] - t[0]) / step)) + 1
    grid = t[0] + step * np.arange(n)
    grid = grid[grid <= t[-1] + 1e-9 * step]
    out = np.column_stack([grid] + [np.interp(grid, t, mat[:, j]) for j in range(1, mat.shape[1])])
    regular = np.ones(len(dt), bool)
    regular[late] = False
    for i in displaced:
        regular[i:i + 2] = False
    gaps = int((whole[regular & (whole > 1)] - 1).sum())
    jit = float(off[regular].max()) if regular.any() else 0.0
    parts = [f"time-step jitter up to {jit:.0%}"]
    if late:
        parts.append(f"{len(late)} late sample(s) of {_span(ratio[late])} Ts, the stamps after each "
                     "following on from it")
    if displaced:
        parts.append(f"{len(displaced)} displaced stamp(s) between steps of "
                     f"{_span(ratio[displaced])} and {_span(ratio[np.asarray(displaced) + 1])} Ts")
    if gaps:
        parts.append(f"{gaps} dropped sample(s) filled")
    msg = f"re-gridded onto a uniform Ts = {step:g} s by linear interpolation ({', '.join(parts)})"
    return grid, out, [msg]


def _span(r: np.ndarray) -> str:
    lo, hi = float(np.min(r)), float(np.max(r))
    return f"{lo:.2f}" if hi - lo < 0.005 else f"{lo:.2f}-{hi:.2f}"


def _off_grid(ratio: np.ndarray, tol: float) -> tuple[list[int], list[int], int | None]:
    """Classify the steps (in median sample times) that are off the whole-sample grid.

    A logged step within `tol` of a whole number 1..`MAX_GAP_SAMPLES` is jitter or dropped
    samples. A step off the grid is repairable in two shapes, each between steps on the grid:
    a late (or early) sample, one step of 0.5..`MAX_GAP_SAMPLES` Ts after which the stamps follow
    on from it (a logger whose loop overran once), and a displaced stamp, a pair of steps that
    sums to whole sample times (one stamp written late or early, the others on the grid). Either
    way the stamps are the times the samples were taken and no gap exceeds `MAX_GAP_SAMPLES`, so
    the same linear interpolation as for jitter repairs it. More than `max(2, 2 %)` such events, or any other shape (a run of
    off-grid steps, a step under half a sample, a gap over `MAX_GAP_SAMPLES`), is an irregular
    record: returns `(late, displaced, None)` or the index of the first bad step last.
    """
    whole = np.round(ratio)
    bad = (np.abs(ratio - whole) > tol) | (whole < 1) | (whole > MAX_GAP_SAMPLES)
    late, displaced = [], []
    i, n = 0, len(ratio)
    while i < n:
        if not bad[i]:
            i += 1
            continue
        j = i
        while j < n and bad[j]:
            j += 1
        run = ratio[i:j]
        pair = float(run.sum())
        if j - i == 1 and 0.5 <= run[0] <= MAX_GAP_SAMPLES:
            late.append(i)
        elif j - i == 2 and abs(pair - round(pair)) <= tol and 1 <= round(pair) <= MAX_GAP_SAMPLES:
            displaced.append(i)
        else:
            return late, displaced, i
        i = j
    if len(late) + len(displaced) > max(2, int(0.02 * n)):
        return late, displaced, int(np.flatnonzero(bad)[0])
    return late, displaced, None


__all__ = ["JITTER_TOLERANCE", "MAX_GAP_SAMPLES", "uniform_time"]
