"""Null distribution of the periodic-drop statistic (`localise.detect_periodic`) on residuals
with no drops: AR(1) noise (phi 0, 0.9, 0.97) plus a slow sine (model error), with and without
the prewhitening of the differences (commit 1ff9ef9), against `PERIOD_THRESHOLD`.

    .venv/bin/python experiments/diagnose_periodic_null.py [--reps 20]

Writes `experiments/results/diagnose_periodic_null.md`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from jthermo.data import atomic_write_text
from jthermo.diagnose import localise as L


def _stat(R, ts, white):
    if white:
        return L.detect_periodic(R, ts)["statistic"]
    keep = L.prewhitened_differences
    L.prewhitened_differences = lambda D: D
    try:
        return L.detect_periodic(R, ts)["statistic"]
    finally:
        L.prewhitened_differences = keep


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    rng = np.random.default_rng(5)
    lines = ["# Periodic-drop statistic on residuals without drops", "",
             f"Made by `python experiments/diagnose_periodic_null.py --reps {args.reps}`; threshold "
             f"{L.PERIOD_THRESHOLD}.", "",
             "| T | Ts s | zones | AR phi | slow sine | prewhitened: median / max | plain: median / max |",
             "|---|---|---|---|---|---|---|"]
    for T, ts, n, phi in [(2400, 0.45, 3, 0.0), (2400, 0.45, 3, 0.9), (600, 4.0, 1, 0.9), (2400, 2.0, 2, 0.97)]:
        sw, sp = [], []
        for _ in range(args.reps):
            w = rng.normal(size=(T, n))
            x = np.zeros_like(w)
            for k in range(1, T):
                x[k] = phi * x[k - 1] + w[k]
            x += 3.0 * np.sin(np.arange(T)[:, None] * ts / 300.0)
            sw.append(_stat(x, ts, True))
            sp.append(_stat(x, ts, False))
        lines.append(f"| {T} | {ts} | {n} | {phi} | 3 sin(t/300 s) | {np.median(sw):.2f} / {max(sw):.2f} | "
                     f"{np.median(sp):.2f} / {max(sp):.2f} |")
        print(lines[-1], flush=True)
    atomic_write_text(Path(args.out) / "diagnose_periodic_null.md", "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
