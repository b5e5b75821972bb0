"""Adam (150 steps, the CLI default) against L-BFGS (tens of evaluations) in `tune_report`,
the library call behind `jthermo tune`: held-out improvement over lambda PI and over the best
classical design, peak sensitivity of the returned loop, gradient evaluations, wall time of the
tuning loop and of the whole report, and the compile time within it.

Every configuration runs in a fresh process with no persistent compilation cache (cold), at
the CLI's defaults (4-zone virtual printer with every realistic effect, 16 rollouts, three
scenarios, the printer and two perturbed copies, the Ms <= 2 guard). Wall times are inflated
by whatever else runs on the machine: the load average is recorded with each.

    python benchmarks/tuning_optimisers.py                      # writes benchmarks/results/tuning_optimisers.md
    python benchmarks/tuning_optimisers.py --rollouts 4 --out /dev/null   # reduced
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def one(family: str, method: str, steps: int, rollouts: int) -> dict:
    """One `tune_report` in this process: the figures of the table."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from jax import monitoring

    from jthermo.tune import tune_report

    spans = []
    monitoring.register_event_duration_secs_listener(
        lambda ev, d, **_: spans.append(d) if ev == "/jax/core/compile/backend_compile_duration"
        else None)
    t0 = time.perf_counter()
    rep = tune_report(family, rollouts=rollouts, steps=steps, optimiser=method)
    total = time.perf_counter() - t0
    msc = rep["ms_constraint"] or {}
    return {"controller": family, "optimiser": method, "steps": steps, "rollouts": rollouts,
            "evaluations": rep["evaluations"], "iterations": len(rep["history"]),
            "improvement_percent": rep["improvement_percent"],
            "improvement_vs_best_classical_percent":
                rep.get("improvement_vs_best_classical_percent"),
            "best_classical": rep.get("best_classical"),
            "changed_powder_improvement_percent":
                (rep.get("changed_powder") or {}).get("improvement_percent"),
            "tuned_cost": rep["tuned_cost"], "chosen_ms": msc.get("chosen_ms"),
            "guard_chosen": rep["guard"].get("chosen"),
            "train_tuned_cost": rep["train_tuned_cost"],
            "total_s": total, "backend_compile_s": sum(spans),
            "load": os.getloadavg()[0]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controllers", default="pi_lambda,lqg")
    ap.add_argument("--adam-steps", type=int, default=150)
    ap.add_argument("--lbfgs-steps", type=int, default=20)
    ap.add_argument("--rollouts", type=int, default=16)
    ap.add_argument("--methods", default="adam,lbfgs")
    ap.add_argument("--one", nargs=2, metavar=("FAMILY", "METHOD"), help=argparse.SUPPRESS)
    ap.add_argument("--out", default=str(RESULTS / "tuning_optimisers.md"))
    args = ap.parse_args(argv)
    steps = {"adam": args.adam_steps, "lbfgs": args.lbfgs_steps}
    if args.one:
        print(json.dumps(one(args.one[0], args.one[1], steps[args.one[1]], args.rollouts)))
        return 0
    rows = []
    env = {**os.environ, "JTHERMO_NO_CACHE": "1"}
    for fam in args.controllers.split(","):
        for m in args.methods.split(","):
            t0 = time.perf_counter()
            out = subprocess.run([sys.executable, __file__, "--one", fam, m, "--rollouts",
                                  str(args.rollouts), "--adam-steps", str(args.adam_steps),
                                  "--lbfgs-steps", str(args.lbfgs_steps)],
                                 env=env, capture_output=True, text=True, check=True)
            row = json.loads(out.stdout.strip().splitlines()[-1])
            row["process_s"] = time.perf_counter() - t0
            rows.append(row)
            print(json.dumps(row), flush=True)
    cmd = "python benchmarks/tuning_optimisers.py" + "".join(
        f" --{k.replace('_', '-')} {getattr(args, k)}" for k in
        ("controllers", "methods", "adam_steps", "lbfgs_steps", "rollouts", "out")
        if getattr(args, k) != ap.get_default(k))
    lines = ["# Tuning optimisers: Adam against L-BFGS in `tune_report` (`jthermo tune`)", "",
             (f"`{cmd}` — fresh process per row, no persistent cache (cold); "
              f"{os.cpu_count()} cores shared with other work: wall times are inflated by the "
              "load average shown (1-minute, at the end of the row)."), "",
             ("| controller | optimiser | steps (max) | iterations | gradient evaluations | "
              "held-out vs lambda PI % | vs best classical % | best classical | "
              "changed powder vs lambda PI % | Ms | report s | backend compile s | "
              "process s | load |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    fmt = lambda v: "—" if v is None else (f"{v:.2f}" if isinstance(v, float) else str(v))
    for r in rows:
        lines.append("| " + " | ".join(fmt(r[k]) for k in (
            "controller", "optimiser", "steps", "iterations", "evaluations",
            "improvement_percent", "improvement_vs_best_classical_percent", "best_classical",
            "changed_powder_improvement_percent", "chosen_ms", "total_s",
            "backend_compile_s", "process_s", "load")) + " |")
    text = "\n".join(lines) + "\n"
    Path(args.out).write_text(text)
    Path(args.out).with_suffix(".json").write_text(json.dumps(rows, indent=1))
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
