"""How long must the designed record be? Separation against the designed record's length.

For the study's cases (`design_experiment_study.CASES`, seed 0) the PRBS estimation and
validation records are diagnosed once; the separating input is then designed for several
lengths (multiples of the validation record) under both criteria of
`jthermo.diagnose.experiment` (`nuisance`: what the diagnosis re-estimates on a new record;
`span`: a constant and the drift hats), and the weakest pair's separation S of the design and of
a PRBS of the same length, limits and switching time is reported. No new record is diagnosed.

    .venv/bin/python experiments/design_experiment_duration.py [--cases body,drift] [--factors 1,2,4]

Writes `experiments/results/design_experiment_duration.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import design_experiment_study as S  # noqa: E402

from jthermo import printer as P  # noqa: E402
from jthermo.data import atomic_write_text  # noqa: E402
from jthermo.diagnose import diagnose, to_json  # noqa: E402
from jthermo.diagnose.experiment import design_experiment  # noqa: E402
from jthermo.inputs import prbs  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default="body,drift")
    ap.add_argument("--factors", default="1,2,4")
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    rows = []
    for name in args.cases.split(","):
        truth, eff, zones, t_est, t_val, levels, hold, noise, measured = S.CASES[name]
        pr = P.make_printer(zones, effects=eff, seed=0)
        u = np.asarray(prbs(1, t_est + t_val, pr.n_inputs, levels=levels, hold=hold), float)
        rec = S.run_printer(pr, u, 2, noise, 0.5 * sum(levels), measured)
        est = rec.replace(u=rec.u[:t_est], y=rec.y[:t_est], w=rec.w[:t_est])
        val = rec.replace(u=rec.u[t_est:], y=rec.y[t_est:], w=rec.w[t_est:], t0=float(t_est))
        res = diagnose(est, val)
        first = S.summary(to_json(res), truth)
        for f in (int(x) for x in args.factors.split(",")):
            for crit in ("nuisance", "span"):
                t0 = time.perf_counter()
                d = design_experiment(res, est, val, duration=f * t_val, n_steps=args.steps, criterion=crit)
                rows.append({"case": name, "truth": truth, "prbs_top": first["top"], "duration_s": f * t_val,
                             "criterion": crit, "rivals": d["rivals"], "pairs": d["pair_separations"],
                             "S_designed": d["separation_designed"], "S_prbs": d["separation_prbs"],
                             "seconds": time.perf_counter() - t0})
                print(rows[-1], flush=True)
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    lines = ["# Separation against the designed record's length", "",
             "Made by `experiments/design_experiment_duration.py` (seed 0; weakest pair's S, noise units). "
             f"Load average (1, 5, 15 min): {load}.", "",
             "| case | PRBS est/val top | models | record s | criterion | S designed | S PRBS | ratio |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['prbs_top']} | {' / '.join(r['rivals'])} | {r['duration_s']} | "
                     f"{r['criterion']} | {r['S_designed']:.3g} | {r['S_prbs']:.3g} | "
                     f"{r['S_designed'] / max(r['S_prbs'], 1e-300):.2f} |")
    out = Path(args.out)
    atomic_write_text(out / "design_experiment_duration.md", "\n".join(lines) + "\n")
    atomic_write_text(out / "design_experiment_duration.json", json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
