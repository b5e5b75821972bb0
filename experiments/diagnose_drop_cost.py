"""CPU cost the irregular drop detection adds to a diagnosis (issue 13's latency concern).

A record on which no drops are found is diagnosed exactly as before, plus `events.detect_drops`
on the estimation residuals (and, on the irregular path, on the validation residuals and two
`events.step_gain`). This times them on residual arrays of the held-out records' largest shapes
(`MAX_EST` = 2400 samples, 1-4 zones, Ts 0.3 s: the widest sweep window), best of 5.

    .venv/bin/python experiments/diagnose_drop_cost.py

Writes `experiments/results/diagnose_drop_cost.md`.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from jthermo.data import atomic_write_text
from jthermo.diagnose.events import detect_drops, flag_matrix, step_gain

OUT = Path(__file__).resolve().parent / "results" / "diagnose_drop_cost.md"


def best_cpu(f, reps=5):
    out = []
    for _ in range(reps):
        c0 = time.process_time()
        f()
        out.append(time.process_time() - c0)
    return min(out)


def main():
    rng = np.random.default_rng(0)
    lines = ["# CPU cost of the irregular drop detection", "",
             "Made by `python experiments/diagnose_drop_cost.py` (best of 5, process CPU seconds; "
             f"load {os.getloadavg()[0]:.1f}).", "",
             "| samples | zones | Ts s | detect_drops s | step_gain s |", "|---|---|---|---|---|"]
    for T, n, ts in [(2400, 1, 0.3), (2400, 3, 0.3), (2400, 4, 0.3), (1200, 4, 2.0), (2400, 9, 0.3)]:
        R = 0.05 * rng.normal(size=(T, n))
        E = flag_matrix(T, [list(range(10, T, 97))] * n)
        a = np.full(n, 1 / 300)
        td = best_cpu(lambda: detect_drops(R, ts))
        tg = best_cpu(lambda: step_gain(R, E, a, ts))
        lines.append(f"| {T} | {n} | {ts} | {td:.4f} | {tg:.4f} |")
        print(lines[-1], flush=True)
    atomic_write_text(OUT, "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
