"""Cost and result of the periodic-drop search before and after fractional trial periods (issue 14).

The search (`jthermo.diagnose.localise.detect_periodic`) runs once per diagnosis on the
baseline's estimation residuals. This times it at a given commit (the module read from git: by default
the whole-sample search, before 79b3b19) against the working tree on the same residuals:
white noise, and drops every 58.17 s at Ts 2.87 s (20.24 samples), every 60 s at Ts 1 s.

    .venv/bin/python experiments/diagnose_period_cost.py [--rev 79b3b19~1]

Writes `experiments/results/diagnose_period_cost.md` (CPU seconds per call, median of 5, and
the period found).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from jthermo.data import atomic_write_text
from jthermo.diagnose import localise as new


def old_module(rev: str):
    src = subprocess.run(["git", "show", f"{rev}:jthermo/diagnose/localise.py"], capture_output=True,
                         text=True, check=True).stdout
    path = Path(tempfile.mkdtemp()) / "localise_old.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("localise_old", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def cpu():
    t = os.times()
    return t.user + t.system


def records():
    rng = np.random.default_rng(0)
    out = []
    for T, n, ts in ((2400, 4, 1.0), (1800, 4, 2.0), (834, 2, 2.875)):
        out.append((f"noise, T {T}, N {n}, Ts {ts}", 0.05 * rng.normal(size=(T, n)), ts, None))
    for T, n, ts, per in ((834, 2, 2.875, 58.172), (2400, 4, 1.0, 60.0)):
        ev = new.event_matrix(T, per / ts, [5] * n)
        R = 0.07 * rng.normal(size=(T, n)) - 0.5 * np.cumsum(ev - ev.mean(0), axis=0)
        out.append((f"drops every {per} s, T {T}, N {n}, Ts {ts}", R, ts, per))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--rev", default="79b3b19~1")
    args = ap.parse_args(argv)
    old = old_module(args.rev)
    lines = ["# The periodic-drop search: whole-sample against fractional trial periods (issue 14)", "",
             (f"Made by `python experiments/diagnose_period_cost.py --rev {args.rev}`; CPU s per call "
              f"(median of 5), 1-min load {os.getloadavg()[0]:.1f} at the start (CPU s are the "
              "load-robust figure)."), "",
             "| residual | before: period s (statistic) | CPU s | after: period s (statistic) | CPU s |",
             "|---|---|---|---|---|"]
    for name, R, ts, _ in records():
        cells = []
        for mod in (old, new):
            t = []
            for _ in range(5):
                c0 = cpu()
                d = mod.detect_periodic(R, ts)
                t.append(cpu() - c0)
            sig = "" if d["significant"] else ", not significant"
            cells += [f"{d['period_s']:.2f} ({d['statistic']:.1f}{sig})", f"{np.median(t):.3f}"]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    atomic_write_text(Path("experiments/results/diagnose_period_cost.md"), "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
