"""Interleaved timing of several ways to compute the same result (shared by the profiling
experiments): each candidate is called once cold and checked against a reference, then all are
repeated in turn so that machine-load drift hits them alike."""

from __future__ import annotations

import statistics
import time

import jax
import numpy as np


def compare_interleaved(cands: dict, reference, baseline: str = "numpy", repeats: int = 5) -> dict:
    """Print cold seconds and max abs error against `reference` for each zero-argument callable
    in `cands`, then the median and minimum warm seconds and the median of the per-repeat ratios
    `baseline seconds / candidate seconds`; returns the warm times `{name: [s, ...]}`."""
    for k, f in cands.items():
        t0 = time.perf_counter()
        out = jax.block_until_ready(f())
        err = float(np.max(np.abs(np.asarray(out) - reference)))
        print(k, "cold", round(time.perf_counter() - t0, 3), "err", err, flush=True)
    times = {k: [] for k in cands}
    for _ in range(repeats):
        for k, f in cands.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f())
            times[k].append(time.perf_counter() - t0)
    for k, v in times.items():
        ratio = statistics.median([n / t for n, t in zip(times[baseline], v)])
        print(k, "median", round(statistics.median(v), 4), "min", round(min(v), 4),
              f"x {baseline}", round(ratio, 2), flush=True)
    return times
