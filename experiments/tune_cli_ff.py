"""The feed-forward controllers at CLI size: `jthermo tune --controller F --plant printer --json` for the
schedule feed-forward families (defaults: 150 Adam steps, 16 rollouts, 600 s scenarios, the
printer and 2 perturbed copies, Ms <= 2 guard, held-out seed 10000, unseen powder PA11), run as
the user runs it, timed from outside (wall, CPU s of the command, load before and after).

    .venv/bin/python experiments/tune_cli_ff.py [--families pi_ff,lqg_ff] [-- EXTRA CLI ARGS]

Writes experiments/results/tune_cli_ff.json (one summary row per family and extra arguments; a
rerun replaces its rows and keeps the others) and its table, experiments/results/tune_cli_ff.md
(`--table-only`: rebuild the table alone). The commands' own JSON goes to a temporary folder.
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path("experiments/results")


def stem(fam: str, extra: list[str]) -> str:
    tag = "".join(ch for ch in "_".join(extra) if ch.isalnum() or ch == "_")
    return f"tune_cli_{fam}" + (f"_{tag}" if tag else "")


def run(fam: str, extra: list[str], tmp: Path) -> dict:
    out = tmp / f"{stem(fam, extra)}.json"
    cmd = [".venv/bin/jthermo", "tune", "--controller", fam, "--plant", "printer", "--json",
           str(out), "--quiet", *extra]
    load0 = os.getloadavg()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    rc = subprocess.run(cmd, check=False).returncode
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    rep = json.loads(out.read_text()) if rc == 0 else {}
    ch = rep.get("changed_powder") or {}
    rb = rep.get("robustness") or {}
    return {"family": fam, "command": " ".join(cmd), "exit": rc, "wall_s": wall, "cpu_s": cpu,
            "load_before": load0, "load_after": os.getloadavg(),
            "tuned_cost": rep.get("tuned_cost"), "start_cost": rep.get("start_cost"),
            "lambda_pi_cost": rep.get("lambda_pi_cost"),
            "vs_lambda_pi_percent": rep.get("improvement_percent"),
            "best_classical": rep.get("best_classical"),
            "best_classical_cost": rep.get("best_classical_cost"),
            "vs_best_classical_percent": rep.get("improvement_vs_best_classical_percent"),
            "unseen_powder": ch.get("powder"),
            "unseen_vs_best_classical_percent": ch.get("improvement_vs_best_classical_percent"),
            "unseen_vs_lambda_pi_percent": ch.get("improvement_percent"),
            "ms": (rb.get("ms") or {}).get("tuned"),
            "guard_chosen": (rep.get("guard") or {}).get("chosen"),
            "json_seconds": rep.get("seconds")}


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default="pi_ff,lqg_ff")
    ap.add_argument("--table-only", action="store_true")
    args = ap.parse_args(argv[:argv.index("--")] if "--" in argv else argv)
    table = RESULTS / "tune_cli_ff.json"
    rows = json.loads(table.read_text()) if table.exists() else {}
    with tempfile.TemporaryDirectory(prefix="jthermo-tune-cli-") as tmp:
        for fam in [] if args.table_only else args.families.split(","):
            row = {**run(fam, extra, Path(tmp)), "extra_args": extra}
            rows[stem(fam, extra)] = row
            table.write_text(json.dumps(rows, indent=1) + "\n")
            print(json.dumps(row), flush=True)

    def f(v, d=1):
        return "—" if v is None else f"{v:.{d}f}"

    lines = ["# `jthermo tune` at CLI size: schedule feed-forward families", "",
             ("`.venv/bin/python experiments/tune_cli_ff.py` runs `jthermo tune --controller F "
              "--plant printer --json ...` (CLI defaults unless extra arguments are listed). "
              "Held-out seed 10000; unseen powder never seen in tuning. Wall times on a shared "
              "2-core machine: compare CPU s, and read the load beside them."), "",
             ("| family | extra args | exit | tuned cost | best classical | vs best classical % "
              "| vs lambda PI % | unseen powder vs best classical % | Ms | guard's iterate "
              "| wall s | CPU s | load before / after |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows.values():
        lines.append(
            f"| {r['family']} | {' '.join(r.get('extra_args', [])) or '—'} | {r['exit']} | "
            f"{f(r['tuned_cost'], 4)} | {r['best_classical']} {f(r['best_classical_cost'], 4)} | "
            f"{f(r['vs_best_classical_percent'])} | {f(r['vs_lambda_pi_percent'])} | "
            f"{r['unseen_powder']} {f(r['unseen_vs_best_classical_percent'])} | {f(r['ms'], 3)} | "
            f"{r['guard_chosen']} | {r['wall_s']:.0f} | {r['cpu_s']:.0f} | "
            f"{r['load_before'][0]:.1f} / {r['load_after'][0]:.1f} |")
    (RESULTS / "tune_cli_ff.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
