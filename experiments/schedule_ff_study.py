"""Reduced study: tune the PI family with schedule feed-forward (`pi_ff`) and the LQG
with it (`lqg_ff`) on the realistic virtual printer and report them on held-out seeds against
every classical design (`best_classical`), lambda PI, the unseen powder, Ms and ±20 % gain.

    .venv/bin/python experiments/schedule_ff_study.py [--families pi_ff,lqg_ff] [--steps 40]
        [--rollouts 4] [--eval-rollouts 4] [--duration 300] [--ensemble 0] [--ff-init 1]
        [--params auto|all|FIELD,...] [--out PATH]

Writes experiments/results/schedule_ff_study.json (one `jthermo tune`-style report per family,
without the tuned controller) and a Markdown table beside it. Settings are recorded in the
output; the defaults are a reduced run (2-core machine), not the CLI's 150 steps × 16 rollouts.
"""

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from jthermo.io import jsonable
from jthermo.tune import tune_report


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="pi_ff,lqg_ff")
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--rollouts", type=int, default=4)
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--eval-rollouts", type=int, default=None,
                    help="held-out rollouts per scenario (default: --rollouts); the same "
                         "held-out seed and draws for every design")
    ap.add_argument("--ensemble", type=int, default=0)
    ap.add_argument("--ff-init", type=int, default=1,
                    help="1: feed-forward taps start at the model-based inverse of each event "
                         "(tune.ff_init); 0: at zero")
    ap.add_argument("--params", default="auto",
                    help="fields tuned: auto (tune_report's default: the feed-forward taps, "
                         "feedback frozen), all (every array leaf), or a comma list")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--table-only", action="store_true",
                    help="only rewrite the Markdown table from the JSON at --out")
    ap.add_argument("--out", default="experiments/results/schedule_ff_study.json")
    args = ap.parse_args(argv)
    out = Path(args.out)
    results = json.loads(out.read_text()) if out.exists() else {}
    for fam in ([] if args.table_only else args.families.split(",")):
        t0, c0 = time.perf_counter(), time.process_time()
        rep = tune_report(fam, steps=args.steps, rollouts=args.rollouts, duration=args.duration,
                          ensemble=args.ensemble, seed=args.seed,
                          eval_rollouts=args.eval_rollouts, ff_init=bool(args.ff_init),
                          params={"auto": "auto", "all": None}.get(
                              args.params, tuple(args.params.split(","))))
        rep.pop("tuned")
        rep["settings"] = vars(args)
        rep["command"] = " ".join([".venv/bin/python", "experiments/schedule_ff_study.py",
                                   *(argv if argv is not None else sys.argv[1:])])
        rep["wall_s"] = time.perf_counter() - t0
        rep["cpu_s"] = time.process_time() - c0
        rep["load"] = os.getloadavg()
        results[fam] = jsonable(rep)
        out.write_text(json.dumps(results, indent=1) + "\n")
        print(fam, {k: rep.get(k) for k in ("tuned_cost", "best_classical", "best_classical_cost",
                                            "improvement_vs_best_classical_percent",
                                            "improvement_percent")}, flush=True)
    rows = [("| family | FF start | start | tuned | lambda PI | best classical | vs lambda PI % "
             "| vs best classical % | unseen powder vs best classical % | Ms tuned "
             "| cost +20 % gain | cost −20 % gain | tuned fields | guard's iterate "
             "| wall s / CPU s (load) |"),
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for fam, r in results.items():
        ch = r.get("changed_powder") or {}
        rb = r.get("robustness") or {}
        init = {True: "inverse", False: "zero"}.get(r.get("ff_init"), "zero (before ff_init)")
        rows.append(f"| {fam} | {init} | {r['start_cost']:.4f} | {r['tuned_cost']:.4f} | "
                    f"{r['lambda_pi_cost']:.4f} | "
                    f"{r['best_classical']} {r['best_classical_cost']:.4f} | "
                    f"{r['improvement_percent']:.1f} | "
                    f"{r['improvement_vs_best_classical_percent']:.1f} | "
                    f"{ch.get('improvement_vs_best_classical_percent', float('nan')):.1f} | "
                    f"{(rb.get('ms') or {}).get('tuned') or float('nan'):.2f} | "
                    f"{(rb.get('gain_plus_20_cost') or {}).get('tuned', float('nan')):.4f} | "
                    f"{(rb.get('gain_minus_20_cost') or {}).get('tuned', float('nan')):.4f} | "
                    f"{r.get('settings', {}).get('params', 'all (before --params)')} | "
                    f"{(r.get('guard') or {}).get('chosen')} | "
                    f"{r.get('wall_s', float('nan')):.0f} / {r.get('cpu_s', float('nan')):.0f} "
                    f"({'/'.join(f'{x:.1f}' for x in r.get('load', ())) or '?'}) |")
    s = {k: v for k, v in results[next(iter(results))]["settings"].items()
         if k not in ("families", "table_only")}
    cmds = sorted({r.get("command", "?") for r in results.values()})
    md = ("# Schedule feed-forward study (reduced run)\n\nCommand(s): "
          + "; ".join(f"`{c}`" for c in cmds) + f"\n\nSettings: {s}. Costs are held-out "
          "means over the tracking, powder and print scenarios (`jthermo.tune.evaluate`).\n\n"
          + "\n".join(rows) + "\n\nClassical designs on the same held-out seeds "
          "(cost): " + "; ".join(f"{fam}: " + ", ".join(
              f"{k} {v:.4f}" for k, v in sorted(r.get("classical_costs", {}).items(),
                                                key=lambda kv: kv[1]))
              for fam, r in results.items()) + "\n")
    msc = {fam: r["ms_constraint"] for fam, r in results.items() if r.get("ms_constraint")}
    if msc:
        # the guard's peak-sensitivity constraint (tune_report ms_max), where recorded
        md += ("\nMs constraint (guard keeps only iterates with Ms ≤ ms_max on the design "
               "model): " + "; ".join(
                   f"{fam}: ms_max {m['ms_max']}, chosen Ms "
                   f"{float('nan') if m['chosen_ms'] is None else m['chosen_ms']:.3f}, "
                   f"satisfied {m['satisfied']}, iterations rejected for Ms "
                   f"{m.get('rejected_for_ms', [])}" for fam, m in msc.items()) + "\n")
    out.with_suffix(".md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
