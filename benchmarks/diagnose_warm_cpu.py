"""Warm in-process CPU seconds of one diagnosis and of its per-zone candidate fits, for same-window
A/B of two code trees (run it once per tree with `PYTHONPATH=TREE`):

    PYTHONPATH=/path/to/tree python benchmarks/diagnose_warm_cpu.py EST.csv VAL.csv

The diagnosis runs twice in the process (the second is warm); printed per run: CPU s, the
findings, the mean validation fit, and each `candidates.fit_zones` call (whether it was a
continuation round with a budget, the problems it ran, its CPU s).
"""

from __future__ import annotations

import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import jthermo.diagnose.candidates as C
from jthermo.data import load_csv
from jthermo.diagnose import diagnose, to_json


def main(argv=None) -> int:
    est_path, val_path = (argv or sys.argv[1:])[:2]
    orig, calls = C.fit_zones, []

    def spy(*a):
        t = time.process_time()
        out = jax.block_until_ready(orig(*a))
        b = np.asarray(a[8]) if len(a) > 8 else None
        calls.append((b is not None, int((b > 0).sum()) if b is not None else a[0].shape[0],
                      round(time.process_time() - t, 1)))
        return out

    C.fit_zones = spy
    est, val = load_csv(est_path), load_csv(val_path)
    for rep in range(2):
        calls.clear()
        t = time.process_time()
        r = to_json(diagnose(est, val))
        print(f"run {rep}: CPU {time.process_time() - t:.1f} s, {[f['mechanism'] for f in r['findings']]}, "
              f"fit {r['augmented']['mean_fit_percent']:.3f} %; fit_zones calls (continued?, problems, CPU s) "
              f"{calls}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
