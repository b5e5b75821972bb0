"""What the per-zone candidate fits pay for their Jacobian width: `fitting.fit_zones` forms one
forward-mode tangent per column up to its static `n_active`, which `select.diagnose` sets from the
widest problem of the call (the surroundings drift's knots), so every problem pays for the
drift's width (the split "widest apart" was measured and not adopted: the `fitting` module's
note). Here the diagnosis's own first `fit_zones` call (the candidates and their extra
starts) is captured and run again (warm, after one compiling call each) as is and split into
calls of problems grouped by their own width (4 ceil(free / 4)), comparing CPU s, costs and
parameters.

    python benchmarks/diagnose_zone_width.py [--record latency | dev:S:I] [--repeats 2]

Writes `benchmarks/results/diagnose_zone_width.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
sys.path.insert(0, str(HERE))
from common import cpu_seconds
from diagnose_zone_convergence import load_record

from jthermo.data import atomic_write_text
from jthermo.diagnose import candidates, fitting, select


def run(args, groups):
    """fit_zones over the problems in `groups` (lists of indices), each group its own call at its
    own width; returns (theta, cost) in the original order and the CPU s."""
    theta0, mask, on, per, shared, lay, n_iter = args
    n_active = 4 * math.ceil(np.asarray(mask).sum(axis=1).max() / 4)
    B = theta0.shape[0]
    th, c = np.zeros(theta0.shape), np.zeros(B)
    c0 = cpu_seconds()
    for g in groups:
        g = np.asarray(g)
        free = int(np.asarray(mask)[g].sum(axis=1).max())
        na = n_active if len(groups) == 1 else 4 * math.ceil(free / 4)
        out = fitting.fit_zones(theta0[g], mask[g], on[g], {k: v[g] for k, v in per.items()},
                                shared, lay, n_iter, na)
        jax.block_until_ready(out)
        th[g], c[g] = np.asarray(out[0]), np.asarray(out[1])
    return th, c, cpu_seconds() - c0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--record", default="latency")
    ap.add_argument("--max-zones", type=int, default=9)
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    est, val = load_record(args.record, args.max_zones)
    calls = []
    orig = candidates.fit_zones
    candidates.fit_zones = lambda *a: calls.append(a[:7]) or orig(*a)
    select.diagnose(est, val)
    candidates.fit_zones = orig
    a = calls[0]
    free = np.asarray(a[1]).sum(axis=1)
    width = 4 * np.ceil(free / 4).astype(int)
    groups = {"one call": [list(range(free.size))],
              "by width": [list(np.nonzero(width == w)[0]) for w in sorted(set(width))],
              "widest apart": [list(np.nonzero(width < width.max())[0]), list(np.nonzero(width == width.max())[0])]}
    res = {k: [] for k in groups}
    for _ in range(args.repeats + 1):       # the first round compiles
        for k, g in groups.items():
            res[k].append(run(a, g))
    base_th, base_c = res["one call"][0][:2]
    rows = []
    for k, grp in groups.items():
        th, c = res[k][-1][:2]
        d = np.abs(th - base_th).max(axis=1)
        worst = [{"problem": int(b), "free": int(free[b]), "theta_diff": float(d[b]),
                  "param": int(np.argmax(np.abs(th[b] - base_th[b]))), "cost": float(base_c[b]),
                  "rel_cost_diff": float(abs(c[b] - base_c[b]) / abs(base_c[b]))}
                 for b in np.argsort(-d)[:6] if d[b] > 0]
        rows.append({"variant": k,
                     "calls": len(grp), "first_cpu_s": res[k][0][2],
                     "cpu_s": float(np.median([r[2] for r in res[k][1:]])),
                     "max_rel_cost_diff": float(np.max(np.abs(c - base_c) / np.abs(base_c))),
                     "max_abs_theta_diff": float(np.max(np.abs(th - base_th))), "worst": worst,
                     "widths": sorted({int(4 * math.ceil(free[g].max() / 4)) for g in map(np.asarray, grp)})})
    L = [f"# Per-zone candidate fits by Jacobian width ({args.record})", "",
         (f"`python benchmarks/diagnose_zone_width.py --record {args.record} --repeats {args.repeats}"
         f"`: the diagnosis's first fit_zones call "
         f"({free.size} problems, n_iter {a[6]}; free parameters {sorted(set(free.astype(int).tolist()))}) "
         f"run as one call and split by width; CPU s (user + sys) the median of {args.repeats} warm rounds; "
         f"load {os.getloadavg()[0]:.1f}."), "",
         "| variant | widths | first call CPU s | warm CPU s | max rel. cost diff | max abs theta diff |",
         "|---|---|---|---|---|---|"]
    for r in rows:
        L.append(f"| {r['variant']} | {r['widths']} | {r['first_cpu_s']:.2f} | {r['cpu_s']:.2f} | "
                 f"{r['max_rel_cost_diff']:.1e} | {r['max_abs_theta_diff']:.1e} |")
    L += ["", "Problems whose parameters moved most (index in the call: candidate-major, zone fastest):", ""]
    for r in rows:
        L += [f"- {r['variant']}: " + "; ".join(f"#{w['problem']} ({w['free']} free) param {w['param']} by "
                                                f"{w['theta_diff']:.2g}, cost rel. {w['rel_cost_diff']:.1e}"
                                                for w in r["worst"])]
    RESULTS.mkdir(exist_ok=True)
    atomic_write_text(RESULTS / "diagnose_zone_width.md", "\n".join(L) + "\n")
    atomic_write_text(RESULTS / "diagnose_zone_width.json", json.dumps(rows, indent=1))
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
