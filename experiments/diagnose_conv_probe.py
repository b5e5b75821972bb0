"""Why the diagnosis misses natural convection on held-out records (issue 14, class `convection_hT`).

For each CASE:SEED_SET of `diagnose_heldout_hard.py` (3 zones at most, as the scored sets):

1. the radiative candidate's per-zone fits (`select.fit_zones`), their Levenberg–Marquardt cost
   after each iteration up to `--hist-iter`, with the candidate refits' heater gains started as
   the baseline left them (`GAIN_START_FLOOR = 1e-12`, the variable projection's own floor:
   the diagnosis before 9b0e942) and at 2 % of the zone's largest (`fitting.GAIN_START_FLOOR`);
2. the whole diagnosis at each `--n-iter` (per-zone candidate iterations, `select.N_ITER`) and
   each floor: every candidate's tests and validation MSE reduction, what is named, the rivals.

    .venv/bin/python experiments/diagnose_conv_probe.py 2:8 2:7 [--n-iter 25,50] [--tag conv]

Writes `experiments/results/diagnose_conv_probe[_TAG].md`.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from jthermo.data import atomic_write_text
from jthermo.diagnose import fitting as F
from jthermo.diagnose import select as S

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H

FLOORS = (1e-12, 0.02)
FLOOR0 = F.GAIN_START_FLOOR


def cost_histories(est, val, floor, n_iter):
    """Per-zone LM cost after each iteration of the radiative candidate's fits `(n, n_iter)`."""
    cap = []
    orig = S.fit_zones

    def wrap(*a, **k):
        out = orig(*a, **k)
        cap.append(np.asarray(out[2]))
        return out

    S.fit_zones, F.GAIN_START_FLOOR = wrap, floor
    try:
        S.diagnose(est, val, mechanisms=("radiative_loss",), n_iter=n_iter)
    finally:
        S.fit_zones, F.GAIN_START_FLOOR = orig, FLOOR0
    return cap[0]


def settled(h, rel=1e-3):
    """First iteration (1-based) whose cost is within `rel` of the final one."""
    return int(np.argmax(h <= h[-1] * (1 + rel))) + 1


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+", help="CASE:SEED_SET")
    ap.add_argument("--n-iter", default="25,50")
    ap.add_argument("--hist-iter", type=int, default=100)
    ap.add_argument("--tag", default="")
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    n_iters = [int(v) for v in args.n_iter.split(",")]
    lines = ["# Convection held-out cases: fit convergence and decision (issue 14)", "",
             f"Made by `python experiments/diagnose_conv_probe.py {' '.join(args.cases)} --n-iter {args.n_iter} "
             f"--hist-iter {args.hist_iter}" + (f" --tag {args.tag}" if args.tag else "") + "`.", "",
             "`floor`: the candidate refits' heater gains start at least at this share of the zone's largest "
             "(1e-12: as the baseline left them, the diagnosis before 9b0e942; 0.02: `fitting.GAIN_START_FLOOR`).", ""]
    t0, c0 = time.perf_counter(), time.process_time()
    for spec in args.cases:
        i, s = map(int, spec.split(":"))
        c = H.draw_case(i, None, 3, s)
        est, val = H.make_record(c)
        lines += [f"## Case {i:02d}, set {s}: {c['kind']}, N = {c['zones']}, Ts = {c['ts']:.2f} s, "
                  f"convective share {c.get('conv_share', float('nan')):.3f}, noise {c['noise']:.3f} °C, "
                  f"surroundings column {'yes' if c['measured_ambient'] else 'no'}", "",
                  f"Radiative candidate, per-zone LM cost (°C²) by iteration ({args.hist_iter} at most):", "",
                  "| floor | zone | start | after 10 | after 25 | after 50 | final | iterations to within 0.1 % of final |",
                  "|---|---|---|---|---|---|---|---|"]
        for fl in FLOORS:
            hs = cost_histories(est, val, fl, args.hist_iter)
            for z, h in enumerate(hs):
                start = h[0]     # cost after the first iteration (the start's is not kept)
                pick = lambda k: f"{h[min(k, h.size) - 1]:.5f}"
                lines.append(f"| {fl:g} | {z + 1} | {start:.5f} (after 1) | {pick(10)} | {pick(25)} | {pick(50)} | "
                             f"{h[-1]:.5f} | {settled(h)} |")
        for fl in FLOORS:
            for ni in n_iters:
                F.GAIN_START_FLOOR = fl
                try:
                    r = S.diagnose(est, val, n_iter=ni)
                finally:
                    F.GAIN_START_FLOOR = FLOOR0
                top = r["findings"][0] if r["findings"] else None
                lines += ["", f"Diagnosis, floor {fl:g}, `N_ITER` {ni}: named "
                          f"{', '.join(f['mechanism'] for f in r['findings']) or 'nothing'}"
                          + (f" (top confidence {top['confidence']:.3f}, rivals {', '.join(top['rivals']) or '-'})"
                             if top else "")
                          + f"; baseline fit {r['baseline']['mean_fit_percent']:.2f} %, augmented "
                          f"{r['augmented']['mean_fit_percent']:.2f} % ({r['augmented']['fit']})", "",
                          "| candidate | validation z (crit.) | estimation LR (crit.) | significant | val. MSE reduction | mean fit % | share / exponent / τ |",
                          "|---|---|---|---|---|---|---|"]
                for cd in r["candidates"]:
                    p = cd["parameters"]
                    extra = {"radiative_loss": lambda: f"share {p['share_of_loss']:.3f}",
                             "input_nonlinearity": lambda: f"exponent {p['exponent']:.3f}",
                             "heat_accumulation": lambda: f"τ {p['time_constant_s']:.0f} s"}.get(cd["mechanism"],
                                                                                                  lambda: "")()
                    lines.append(f"| {cd['mechanism']} | {cd['validation_z']:.2f} ({cd['validation_z_critical']:.2f}) | "
                                 f"{cd['estimation_lr']:.1f} ({cd['estimation_lr_critical']:.1f}) | {cd['significant']} | "
                                 f"{cd['val_reduction']:.4f} | {cd['mean_fit_percent']:.2f} | {extra} |")
        lines.append("")
    load = os.getloadavg()
    lines += ["", f"Wall {time.perf_counter() - t0:.0f} s, CPU {time.process_time() - c0:.0f} s (user+sys of this "
              f"process); 1/5/15-min load {load[0]:.1f}/{load[1]:.1f}/{load[2]:.1f} at the end (shared 2-core machine).", ""]
    name = "diagnose_conv_probe" + (f"_{args.tag}" if args.tag else "") + ".md"
    atomic_write_text(Path(args.out) / name, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
