"""Would the joint forward selection lose findings if it tried only the mechanisms that were
significant alone (per-zone candidate tests)? Counted from stored diagnosis results.

For every record in the given results files (held-out studies' `records`, the in-class study's
`cases`), each joint addition tried (`combinations`) is looked up in the record's per-zone
candidate table: an addition accepted although its mechanism was not significant alone would be
lost by a pool restricted to the significant ones.

    python experiments/diagnose_joint_pool_evidence.py [FILES...]   (default: the current diagnose_heldout_hard and diagnose_study results)

Writes `experiments/results/diagnose_joint_pool_evidence.md`.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ["diagnose_heldout_hard.json", "diagnose_study.json"]


def _list(v):
    return json.loads(v.replace("'", '"')) if isinstance(v, str) else v


def main() -> None:
    files = sys.argv[1:] or [str(ROOT / "experiments" / "results" / f) for f in DEFAULT]
    lines = ["# Joint additions against per-zone significance", "",
             "`python experiments/diagnose_joint_pool_evidence.py`: joint additions tried / accepted, and "
             "accepted although not significant alone (lost if the pool held only significant mechanisms).", "",
             "| results file | records with a joint stage | additions tried | accepted | accepted, not significant alone | "
             "records whose augmented model would change |", "|---|---|---|---|---|---|"]
    for f in files:
        d = json.loads(Path(f).read_text())
        recs = d.get("records") or d.get("cases") or []
        n_rec = tried = acc = lost = changed = 0
        for r in recs:
            cands, combs = r.get("candidates"), r.get("combinations")
            if not cands or not combs:
                continue
            try:
                cands, combs = _list(cands), _list(combs)
            except (ValueError, AttributeError):
                continue
            n_rec += 1
            sig = {c["mechanism"]: c.get("significant") for c in cands}
            hit = False
            for c in combs:
                tried += 1
                if c.get("accepted"):
                    acc += 1
                    if not sig.get(c["mechanisms"][-1]):
                        lost += 1
                        hit = True
            changed += hit
        lines.append(f"| {Path(f).name} | {n_rec} | {tried} | {acc} | {lost} | {changed} |")
    out = ROOT / "experiments" / "results" / "diagnose_joint_pool_evidence.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
