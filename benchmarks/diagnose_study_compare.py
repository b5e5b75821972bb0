"""Two runs of `experiments/diagnose_study.py` (e.g. two source trees), case by case: the same
answers? Verdict, top finding, findings, and the largest relative difference of the fits and
the reported parameters; CPU s beside.

    python benchmarks/diagnose_study_compare.py A.json B.json --out results/x.md
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _nums(p) -> list:
    if isinstance(p, dict):
        return [v for k in sorted(p) for v in _nums(p[k])]
    if isinstance(p, (list, tuple)):
        return [v for x in p for v in _nums(x)]
    return [float(p)] if isinstance(p, (int, float)) and not isinstance(p, bool) else []


def _rel(a, b) -> float:
    a, b = _nums(a), _nums(b)
    if len(a) != len(b):
        return float("inf")
    return max([abs(x - y) / max(abs(y), 1e-12) for x, y in zip(a, b)], default=0.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    A = {c["case"]: c for c in json.loads(Path(args.a).read_text())["cases"]}
    B = {c["case"]: c for c in json.loads(Path(args.b).read_text())["cases"]}
    lines = [f"# Diagnosis study, two runs case by case", "",
             f"`python benchmarks/diagnose_study_compare.py {args.a} {args.b} --out {args.out}`", "",
             "| case | same verdict, top, findings | A top / found | fits rel. diff | parameters rel. diff "
             "| A CPU s | B CPU s | A load | B load |", "|---|---|---|---|---|---|---|---|---|"]
    for k, a in A.items():
        b = B.get(k)
        if b is None:
            lines.append(f"| {k} | missing in B | | | | | | | |")
            continue
        same = all(a[f] == b[f] for f in ("verdict", "top", "found"))
        lines.append(f"| {k} | {same} | {a['top']} / {', '.join(a['found'])} | "
                     f"{_rel([a['base_fit'], a['aug_fit'], a['gain']], [b['base_fit'], b['aug_fit'], b['gain']]):.1e} | "
                     f"{_rel(a['params'], b['params']):.1e} | {a['cpu_seconds']:.0f} | {b['cpu_seconds']:.0f} | "
                     f"{a['load']:.2f} | {b['load']:.2f} |")
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
