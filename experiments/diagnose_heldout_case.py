"""One case of the harder diagnosis study in detail: every candidate's tests, the
dead-time scan and the periodic search (why a case is missed).

    .venv/bin/python experiments/diagnose_heldout_case.py --case 12 --seed-set 5 [--max-zones 3]

Writes `experiments/results/diagnose_heldout_case_<case>_set<S>.md` and `.json`: the record
(`diagnose_heldout_hard.draw_case`), what was named, each candidate's validation z and estimation
likelihood ratio against their critical values, the validation MSE reduction, the fitted
parameters, the dead-time scan's best and the periodic search.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose, to_json

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", type=int, required=True)
    ap.add_argument("--seed-set", type=int, default=0)
    ap.add_argument("--max-zones", type=int, default=9)
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    c = H.draw_case(args.case, None, args.max_zones, args.seed_set)
    est, val = H.make_record(c)
    t0, c0 = time.perf_counter(), os.times()
    res = to_json(diagnose(est, val))
    wall = time.perf_counter() - t0
    cpu = sum(os.times()[:2]) - sum(c0[:2])
    ds = res["localisation"]["delay_scan"]
    k = int(np.argmin(ds["cost"]))
    name = "diagnose_heldout_case"
    head = (f"Made by `python experiments/diagnose_heldout_case.py --case {args.case} --seed-set "
            f"{args.seed_set} --max-zones {args.max_zones}`; {wall:.0f} s wall, {cpu:.0f} CPU s, "
            f"1-min load {os.getloadavg()[0]:.1f}.")
    record = (f"- record: N = {c['zones']}, Ts = {c['ts']:.3f} s, {c['n_est']} estimation and "
              f"{c['n_val']} validation samples, noise {c['noise']:.3f} °C, measured surroundings "
              f"{c['measured_ambient']}; physics {json.dumps(H.describe(c))}")
    named = [(f["mechanism"], round(f["confidence"], 3), f["rivals"]) for f in res["findings"]]
    scan = (f"- dead-time scan: best {ds['delays_s'][k]:.3f} s, MSE {ds['cost'][k]:.6f} against "
            f"{ds['baseline_cost']:.6f} without")
    cols = ("| candidate | validation z / critical | estimation LR / critical | significant | "
            "validation MSE reduction | fit gain (pts) | parameters |")
    lines = [(f"# Diagnosis case {args.case:02d} ({c['kind']}) of seed set {args.seed_set} in detail "
              "(a case studied: development data for what changes on it)"), "",
             head, "", record, f"- verdict {res['verdict']}; named {named}",
             f"- fit {res['baseline']['mean_fit_percent']:.2f} → {res['augmented']['mean_fit_percent']:.2f} %",
             scan, f"- periodic search: {json.dumps(res['localisation']['periodic'])}", "",
             cols, "|---|---|---|---|---|---|---|"]
    for r in res["candidates"]:
        lines.append(f"| {r['mechanism']} | {r['validation_z']:.3f} / {r['validation_z_critical']:.2f} | "
                     f"{r['estimation_lr']:.2f} / {r['estimation_lr_critical']:.2f} | {r['significant']} | "
                     f"{r['val_reduction']:.4f} | {r['fit_gain']:.2f} | "
                     f"{json.dumps(r['parameters'], default=float)[:160]} |")
    out = Path(args.out)
    atomic_write_text(out / f"{name}.md", "\n".join(lines) + "\n")
    atomic_write_text(out / f"{name}.json", json.dumps({"case": H.describe(c), "result": res}, default=float))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
