"""Issue 16 item 3 on a reduced run: the schedule feed-forward PI (`pi_ff`) tuned with and
without the smooth peak-sensitivity penalty in the cost (`tune_report(ms_weight=...)`), the
Ms <= 2 guard on in both. Reports the Ms of the returned loop on the design model, whether the
guard found an iterate within the limit (or fell back to the start), and the held-out costs.

Reduced settings (one process, no persistent cache): 4-zone virtual printer, `--rollouts`
rollouts, no plant ensemble, `--duration` s scenarios, L-BFGS with at most `--steps`
iterations, no changed-powder or ±20 % gain evaluation.

    python benchmarks/tuning_ms_penalty.py       # writes benchmarks/results/tuning_ms_penalty.md
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

from jthermo.tune import tune_report

RESULTS = Path(__file__).resolve().parent / "results"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="pi_ff")
    ap.add_argument("--weights", default="0,10")
    ap.add_argument("--rollouts", type=int, default=4)
    ap.add_argument("--steps", type=int, default=15)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--out", default=str(RESULTS / "tuning_ms_penalty.md"))
    args = ap.parse_args(argv)
    rows = []
    for w in (float(v) for v in args.weights.split(",")):
        t0 = time.perf_counter()
        rep = tune_report(args.controller, rollouts=args.rollouts, steps=args.steps,
                          duration=args.duration, ensemble=0, changed_powder=None,
                          check_robustness=False, optimiser="lbfgs", ms_weight=w)
        msc = rep["ms_constraint"]
        row = {"ms_weight": w, "chosen_ms": msc["chosen_ms"], "satisfied": msc["satisfied"],
               "guard_chosen": rep["guard"].get("chosen"),
               "rejected_for_ms": msc["rejected_for_ms"],
               "start_cost": rep["start_cost"], "tuned_cost": rep["tuned_cost"],
               "improvement_vs_start_percent": 100 * (1 - rep["tuned_cost"] / rep["start_cost"]),
               "improvement_percent": rep["improvement_percent"],
               "improvement_vs_best_classical_percent":
                   rep.get("improvement_vs_best_classical_percent"),
               "evaluations": rep["evaluations"], "seconds": time.perf_counter() - t0,
               "load": os.getloadavg()[0]}
        rows.append(row)
        print(json.dumps(row), flush=True)
    cmd = "python benchmarks/tuning_ms_penalty.py" + "".join(
        f" --{k} {getattr(args, k)}" for k, d in (("weights", "0,10"), ("rollouts", 4),
                                                    ("steps", 15), ("duration", 600.0))
        if getattr(args, k) != d) + ("" if args.out == ap.get_default("out")
                                     else f" --out {args.out}")
    lines = [f"# {args.controller} with the Ms penalty in the tuning cost (reduced run)", "",
             (f"`{cmd}`: {args.rollouts} rollouts, {args.duration:g} s scenarios, one plant, "
              f"L-BFGS ≤ {args.steps} iterations, Ms ≤ 2 guard; held-out seed of `tune_report`. "
              f"Wall times inflated by the load average shown ({os.cpu_count()} cores, "
              "shared)."),
             "",
             ("| ms_weight | Ms of the returned loop | Ms ≤ 2 | guard's iterate "
              "(None: the start) | iterates rejected for Ms | held-out cost start → returned "
              "| vs start % | vs lambda PI % | vs best classical % | evaluations | s | load |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['ms_weight']:g} | {r['chosen_ms']:.3f} | {r['satisfied']} | "
            f"{r['guard_chosen']} | {r['rejected_for_ms']} | {r['start_cost']:.4f} → "
            f"{r['tuned_cost']:.4f} | {r['improvement_vs_start_percent']:.1f} | "
            f"{r['improvement_percent']:.1f} | "
            f"{r['improvement_vs_best_classical_percent']:.1f} | {r['evaluations']} | "
            f"{r['seconds']:.0f} | {r['load']:.1f} |")
    text = "\n".join(lines) + "\n"
    Path(args.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
