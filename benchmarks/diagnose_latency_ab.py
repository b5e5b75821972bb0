"""The `jthermo diagnose` latency row (`benchmarks/latency.py`: cold = empty cache, warm = a second
process) for two code trees, interleaved A B A B in one window: A a tree given by `--a` (e.g. a
`git archive main` unpacked in /tmp), put first on `PYTHONPATH`; B this checkout.

    git archive main | tar -x -C /tmp/main_tree
    python benchmarks/diagnose_latency_ab.py --a /tmp/main_tree --a-label main --rounds 2

Writes `benchmarks/results/diagnose_latency_ab.md` and `.json`: wall, CPU (user + system of
the child process) and the 1-min load before each run, the verdict and top finding.
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
sys.path.insert(0, str(HERE))
from latency import measure

from jthermo.data import atomic_write_text


def _imported_from(cwd: str) -> str:
    """Where a process started as `latency.measure` starts them (in `cwd`, this environment)
    imports `jthermo` from."""
    return subprocess.run([sys.executable, "-c", "import jthermo; print(jthermo.__file__)"], cwd=cwd,
                          capture_output=True, text=True, check=True).stdout.strip()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--a", required=True, help="root of the A code tree")
    ap.add_argument("--a-label", default="A")
    ap.add_argument("--b-label", default=None)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args(argv)
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          cwd=HERE, check=False).stdout.strip()
    b_label = args.b_label or f"this checkout ({head})"
    base_pp = os.environ.get("PYTHONPATH", "")
    runs = []
    for r in range(args.rounds):
        for label, root in ((args.a_label, args.a), (b_label, None)):
            os.environ["PYTHONPATH"] = (str(Path(root).resolve()) + (os.pathsep + base_pp if base_pp else "")
                                        if root else base_pp)
            with tempfile.TemporaryDirectory() as d:
                used = _imported_from(d)
                if root and not used.startswith(str(Path(root).resolve())):
                    raise SystemExit(f"A imports jthermo from {used}, not from {root}")
                row = measure("diagnose", Path(d), False)
            runs.append({"round": r, "code": label, "jthermo_from": "the A tree" if root else "the checkout", **row})
    os.environ["PYTHONPATH"] = base_pp
    L = ["# `jthermo diagnose` latency, A/B", "",
         (f"`python benchmarks/diagnose_latency_ab.py --a {args.a} --a-label {args.a_label} --rounds {args.rounds}"
         f"`: the latency record (`benchmarks/latency.py`), each code "
         "cold (empty cache) then warm (second process), the codes interleaved; wall s, CPU s (user + system "
         "of the process), load before (1-min)."), "",
         "| round | code | cold wall s | cold CPU s | cold load | warm wall s | warm CPU s | warm load | result |",
         "|---|---|---|---|---|---|---|---|---|"]
    for x in runs:
        c, w = x["cold"], x["warm"]
        L.append(f"| {x['round']} | {x['code']} | {c['wall_s']:.1f} | {c.get('cpu_s', float('nan')):.1f} | "
                 f"{c['load_before'].split()[0]} | {w['wall_s']:.1f} | {w.get('cpu_s', float('nan')):.1f} | "
                 f"{w['load_before'].split()[0]} | {w.get('verdict', w.get('error', ''))}, {w.get('top_finding')} |")
    out = HERE / "results"
    atomic_write_text(out / "diagnose_latency_ab.md", "\n".join(L) + "\n")
    atomic_write_text(out / "diagnose_latency_ab.json", json.dumps(runs, indent=1))
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
