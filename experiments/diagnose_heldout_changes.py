"""Case by case, what changed between two runs of `diagnose_heldout_hard.py` (issue 14).

    .venv/bin/python experiments/diagnose_heldout_changes.py BEFORE_TAG AFTER_TAG[,EXTRA_TAG...] --tag OUT

Reads `experiments/results/diagnose_heldout_hard_<tag>.json`; records of the after tags are
pooled (a case re-run alone, e.g. after a crash, in its own file). Writes
`experiments/results/diagnose_heldout_changes_<OUT>.md`: top-1 and nulls of both, CPU seconds
(user+sys) of the cases both hold, and every case whose top finding or rivals changed.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

RES = Path(__file__).resolve().parent / "results"


def load(tags):
    rows, args = {}, []
    for t in tags.split(","):
        d = json.loads((RES / f"diagnose_heldout_hard_{t}.json").read_text())
        args.append(d["meta"]["args"])
        for r in d["records"]:
            rows.setdefault(r["case"], r)
    return rows, args


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--tag", required=True)
    a = ap.parse_args(argv)
    b, ab = load(a.before)
    f, af = load(a.after)
    both = sorted(set(b) & set(f))
    score = lambda rs: (sum(rs[c]["correct"] for c in both if rs[c]["kind"] != "null"),
                        sum(rs[c]["kind"] != "null" for c in both),
                        sum(rs[c]["correct"] for c in both if rs[c]["kind"] == "null"),
                        sum(rs[c]["kind"] == "null" for c in both))
    sb, sf = score(b), score(f)
    cpu = lambda rs: sum(rs[c]["cpu_s"] for c in both)
    lines = [f"# Diagnosis held-out cases: {a.before} → {a.after} (issue 14)", "",
             f"Made by `python experiments/diagnose_heldout_changes.py {a.before} {a.after} --tag {a.tag}`; "
             f"before: `{'`; `'.join(ab)}`, after: `{'`; `'.join(af)}`.", "",
             f"- top-1 on mechanism cases: {sb[0]}/{sb[1]} → {sf[0]}/{sf[1]}",
             f"- nulls quiet: {sb[2]}/{sb[3]} → {sf[2]}/{sf[3]}",
             f"- CPU s (user+sys, the {len(both)} cases, each run under its own load): {cpu(b):.0f} → {cpu(f):.0f}",
             "", "| case | kind | before: top (rivals) | after: top (rivals) | right before → after | cpu s before → after |",
             "|---|---|---|---|---|---|"]
    for c in both:
        rb, rf = b[c], f[c]
        if (rb["top"], rb["rivals"]) != (rf["top"], rf["rivals"]):
            lines.append(f"| {c} | {rb['kind']} | {rb['top']} ({', '.join(rb['rivals']) or '-'}) | {rf['top']} "
                         f"({', '.join(rf['rivals']) or '-'}) | {rb['correct']} → {rf['correct']} | "
                         f"{rb['cpu_s']:.0f} → {rf['cpu_s']:.0f} |")
    out = RES / f"diagnose_heldout_changes_{a.tag}.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
