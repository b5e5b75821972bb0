"""`jthermo simulate` (N = 16, B = 256, T = 3600: the latency row), or another command of
`benchmarks/latency.py` (`--command tune_pi`), from two source trees in turn, at the same load:
an earlier revision against this checkout, cold and warm, interleaved.

On a shared machine the wall clock follows the load, so `benchmarks/latency.py` alone cannot
say whether a change helped; here both trees run back to back (cold base, cold this, warm
base, warm this), each in its own process with its own fresh `JTHERMO_CACHE_DIR`, and the
process's CPU seconds (user + system) are recorded next to the wall seconds.

    git archive REV | (mkdir -p BASE && tar -x -C BASE)
    python benchmarks/simulate_latency_ab.py --base BASE --base-label REV
    python benchmarks/simulate_latency_ab.py --base BASE --base-label REV --command tune_pi
        # -> results/tuning_latency_ab_tune_pi.md
    python benchmarks/simulate_latency_ab.py --base BASE --base-label REV --this AFTER \
        --this-label REV2 --repeats 3

`--this` takes a second snapshot in place of this checkout (other work in the checkout then
stays out of the comparison); `--repeats K` runs the cold/warm pairs K times (each cold run
with a new empty cache) and adds the medians.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from latency import COMMANDS, _jthermo


def _cells(run: dict) -> str:
    """`wall (compile / run) | CPU | load` of one run."""
    nan = float("nan")
    return (f"{run['wall_s']:.1f} ({run.get('compile_s', nan):.1f} / {run.get('run_s', nan):.1f})"
            f" | {run['cpu_s']:.1f} | {run['load_before'].split()[0]}")


def _medians(runs: list[dict], names: list[str]) -> list[str]:
    """Markdown rows: the median of each figure over the repeats, per tree and phase."""
    out = ["", f"Medians over the {len(runs)} runs:", "",
           ("| tree | cold wall s | cold CPU s | warm wall s | warm CPU s | warm compile s | "
            "warm run s |"), "|---|---|---|---|---|---|---|"]
    for n in names:
        def med(ph, key, n=n):
            return statistics.median(r[n][ph].get(key, float("nan")) for r in runs)

        out.append(f"| {n} | {med('cold', 'wall_s'):.2f} | {med('cold', 'cpu_s'):.2f} | "
                   f"{med('warm', 'wall_s'):.2f} | {med('warm', 'cpu_s'):.2f} | "
                   f"{med('warm', 'compile_s'):.2f} | {med('warm', 'run_s'):.2f} |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="source tree of the earlier revision")
    ap.add_argument("--base-label", required=True, help="how the table names it (e.g. a commit)")
    ap.add_argument("--command", default="simulate", choices=("simulate", "tune_pi", "tune_lqg"))
    ap.add_argument("--out", default=None,
                    help="default benchmarks/results/simulate_latency_ab.md")
    ap.add_argument("--this", default=None, help="source tree to compare (default: this checkout)")
    ap.add_argument("--this-label", default="this checkout")
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    out = args.out or str(HERE / "results" / "simulate_latency_ab.md")
    this = Path(args.this).resolve() if args.this else HERE.parent
    trees = {args.base_label: Path(args.base).resolve(), args.this_label: this}
    argv = COMMANDS[args.command][0]
    env0 = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env0.pop("JTHERMO_NO_CACHE", None)
    runs: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="jthermo-ab-") as tmp:
        for rep in range(args.repeats):
            rows: dict = {name: {} for name in trees}
            caches = {name: str(Path(tmp) / f"cache-{rep}-{i}") for i, name in enumerate(trees)}
            for phase in ("cold", "warm"):
                for name, tree in trees.items():
                    env = dict(env0, PYTHONPATH=str(tree), JTHERMO_CACHE_DIR=caches[name])
                    rows[name][phase] = _jthermo(argv, env, Path(tmp) / f"{phase}.json",
                                                 cwd=str(tree))
                    print(rep, name, phase, rows[name][phase], flush=True)
            runs.append(rows)
    result = "mse" if args.command == "simulate" else "held-out improvement %"
    lines = [f"# `jthermo {argv[0]}` latency: an earlier revision against this checkout", "",
             (f"`python benchmarks/simulate_latency_ab.py --base BASE --base-label {args.base_label}"
              f"{'' if args.command == 'simulate' else ' --command ' + args.command}"
              + (f" --this AFTER --this-label {args.this_label}" if args.this else "")
              + (f" --repeats {args.repeats}" if args.repeats > 1 else "") + "` "
              f"(BASE: `git archive {args.base_label}`"
              + (f", AFTER: `git archive {args.this_label}`" if args.this else "")
              + f"); command `jthermo {' '.join(argv)}`; cold = "
              "empty compilation cache, warm = a second process with that cache; run order: cold "
              "base, cold this, warm base, warm this. 2 CPU cores shared with other jobs: the wall "
              "seconds follow the load (1-minute average before each run), the CPU seconds (user + "
              "system of the process, all threads) much less."), "",
             ("| tree | cold wall s (compile / run) | cold CPU s | cold load | warm wall s "
              f"(compile / run) | warm CPU s | warm load | {result} (warm) |"),
             "|---|---|---|---|---|---|---|---|"]
    for rep, rows in enumerate(runs):
        for name, r in rows.items():
            res = r["warm"].get("mse" if args.command == "simulate" else "improvement_percent")
            label = name if len(runs) == 1 else f"{name} (run {rep + 1})"
            lines.append(f"| {label} | {_cells(r['cold'])} | {_cells(r['warm'])} | "
                         f"{float('nan') if res is None else res:.10g} |")
    if len(runs) > 1:
        lines += _medians(runs, list(trees))
    lines += ["", "1-minute load after each run: " + "; ".join(
        ", ".join(f"{n} {ph} {r[ph]['load_after']}" for n, r in rows.items()
                  for ph in ("cold", "warm")) for rows in runs)]
    text = "\n".join(lines) + "\n"
    Path(out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
