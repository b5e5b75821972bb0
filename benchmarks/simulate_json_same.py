"""The `--json` report of `jthermo simulate` from two source trees: every field but the
timings (`seconds`, `compile_s`, `run_s`) compared for equality, bit for bit (floats as
written by `json`, 17 significant digits), for a few seeds and controllers.

    git archive REV | (mkdir -p BASE && tar -x -C BASE)
    python benchmarks/simulate_json_same.py --base BASE --base-label REV --out results/...md
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
TIMINGS = ("seconds", "compile_s", "run_s")
CASES = (("pi", 16, 256, 3600, 0), ("pi", 16, 256, 3600, 7), ("pi", 4, 32, 600, 3),
         ("lqg", 4, 32, 600, 0))


def _report(tree: str | None, cache: str, case) -> dict:
    ctrl, zones, rollouts, duration, seed = case
    env = {**os.environ, "JTHERMO_CACHE_DIR": cache}
    if tree is not None:
        env["PYTHONPATH"] = tree
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "r.json"
        subprocess.run([sys.executable, "-m", "jthermo.cli", "simulate", "--scenario", "tracking",
                        "--controller", ctrl, "--zones", str(zones), "--rollouts", str(rollouts),
                        "--duration", str(duration), "--seed", str(seed), "--quiet",
                        "--json", str(out)], check=True, env=env, cwd=tree)
        rep = json.loads(out.read_text())
    return {k: v for k, v in rep.items() if k not in TIMINGS}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True)
    ap.add_argument("--base-label", required=True)
    ap.add_argument("--out", default="-")
    args = ap.parse_args()
    rows = ["| controller | zones | rollouts | duration s | seed | fields | equal | mse base | "
            "mse this |", "|---|---|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as ca, tempfile.TemporaryDirectory() as cb:
        for case in CASES:
            a, b = _report(args.base, ca, case), _report(None, cb, case)
            rows.append(f"| {' | '.join(map(str, case))} | {len(a)} | "
                        f"{'yes' if a == b else 'NO'} | {a['metrics']['mse']!r} | "
                        f"{b['metrics']['mse']!r} |")
    text = "\n".join([f"# `jthermo simulate --json`: {args.base_label} against this checkout", "",
                      f"`python benchmarks/simulate_json_same.py --base BASE --base-label "
                      f"{args.base_label}` (BASE: `git archive {args.base_label}`): every report "
                      "field but the timings, scenario tracking.", "", *rows]) + "\n"
    print(text)
    if args.out != "-":
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
