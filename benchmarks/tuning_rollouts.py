"""Training size and Adam settings against the held-out result: `tune_report` at the CLI's
other defaults (4 zones, PA12, seed 0) with `rollouts` training rollouts per scenario and
plant, `steps` Adam steps of learning rate `lr`, always judged on 16 held-out rollouts
(`eval_rollouts`), so the figures compare.

    python benchmarks/tuning_rollouts.py --controller pi --rollouts 8
    python benchmarks/tuning_rollouts.py --controller lqg --rollouts 16 --steps 30 --lr 0.1

Appends one JSON line per run to benchmarks/results/tuning_rollouts.jsonl (wall and process
CPU seconds, the 1-minute load at the start: wall times are inflated by the shared cores).
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

from jthermo.tune import tune_report  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "tuning_rollouts.jsonl"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="pi")
    ap.add_argument("--rollouts", type=int, nargs="+", default=[8])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--eval-rollouts", type=int, default=16)
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--train-dtype", default=None, choices=("float32",),
                    help="training rollouts in this precision (held-out in float64)")
    ap.add_argument("--cache", action="store_true",
                    help="use the jthermo persistent compilation cache (CPU s then exclude most "
                         "compiles; the held-out figures do not depend on it)")
    args = ap.parse_args(argv)
    if args.cache:
        from jthermo import runtime

        runtime.enable_cache()
    for r in args.rollouts:
        load = os.getloadavg()[0]
        t0, c0 = time.perf_counter(), time.process_time()
        rep = tune_report(args.controller, rollouts=r, steps=args.steps, lr=args.lr,
                          eval_rollouts=args.eval_rollouts, train_dtype=args.train_dtype)
        row = {"controller": rep["controller"], "rollouts": r, "steps": args.steps,
               "lr": args.lr, "train_dtype": args.train_dtype,
               "eval_rollouts": args.eval_rollouts,
               "improvement_percent": rep["improvement_percent"],
               "changed_powder_improvement_percent":
                   (rep["changed_powder"] or {}).get("improvement_percent"),
               "improvement_vs_best_classical_percent":
                   rep.get("improvement_vs_best_classical_percent"),
               "guard_chosen": rep["guard"].get("chosen"),
               "chosen_ms": (rep["ms_constraint"] or {}).get("chosen_ms"),
               "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0,
               "load_at_start": load, "cache": bool(args.cache)}
        print(json.dumps(row), flush=True)
        with open(OUT, "a") as fh:
            fh.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
