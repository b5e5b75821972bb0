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
"""

from __future__ import annotations

import argparse
import os
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="source tree of the earlier revision")
    ap.add_argument("--base-label", required=True, help="how the table names it (e.g. a commit)")
    ap.add_argument("--command", default="simulate", choices=("simulate", "tune_pi", "tune_lqg"))
    ap.add_argument("--out", default=None,
                    help="default results/simulate_latency_ab.md or tuning_latency_ab_COMMAND.md")
    args = ap.parse_args()
    out = args.out or str(HERE / "results" / ("simulate_latency_ab.md" if args.command == "simulate"
                                              else f"tuning_latency_ab_{args.command}.md"))
    trees = {args.base_label: Path(args.base).resolve(), "this checkout": HERE.parent}
    argv = COMMANDS[args.command][0]
    env0 = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env0.pop("JTHERMO_NO_CACHE", None)
    rows: dict = {name: {} for name in trees}
    with tempfile.TemporaryDirectory(prefix="jthermo-ab-") as tmp:
        caches = {name: str(Path(tmp) / f"cache-{i}") for i, name in enumerate(trees)}
        for phase in ("cold", "warm"):
            for name, tree in trees.items():
                env = dict(env0, PYTHONPATH=str(tree), JTHERMO_CACHE_DIR=caches[name])
                rows[name][phase] = _jthermo(argv, env, Path(tmp) / f"{phase}.json", cwd=str(tree))
                print(name, phase, rows[name][phase], flush=True)
    result = "mse" if args.command == "simulate" else "held-out improvement %"
    lines = [f"# `jthermo {argv[0]}` latency: an earlier revision against this checkout", "",
             (f"`python benchmarks/simulate_latency_ab.py --base BASE --base-label {args.base_label}"
              f"{'' if args.command == 'simulate' else ' --command ' + args.command}` "
              f"(BASE: `git archive {args.base_label}`); command `jthermo {' '.join(argv)}`; cold = "
              "empty compilation cache, warm = a second process with that cache; run order: cold "
              "base, cold this, warm base, warm this. 2 CPU cores shared with other jobs: the wall "
              "seconds follow the load (1-minute average before each run), the CPU seconds (user + "
              "system of the process, all threads) much less."), "",
             ("| tree | cold wall s (compile / run) | cold CPU s | cold load | warm wall s "
              f"(compile / run) | warm CPU s | warm load | {result} (warm) |"),
             "|---|---|---|---|---|---|---|---|"]
    for name, r in rows.items():
        res = r["warm"].get("mse" if args.command == "simulate" else "improvement_percent")
        lines.append(f"| {name} | {_cells(r['cold'])} | {_cells(r['warm'])} | "
                     f"{float('nan') if res is None else res:.10g} |")
    lines += ["", "1-minute load after each run: " + ", ".join(
        f"{n} {ph} {r[ph]['load_after']}" for n, r in rows.items() for ph in ("cold", "warm"))]
    text = "\n".join(lines) + "\n"
    Path(out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
