"""Issue 14: where the nested restarts acted and which candidates still end below their nested
baseline (negative estimation likelihood ratio), from diagnose_heldout_hard's JSON results.

    python experiments/diagnose_nested_start_table.py dev1_start dev1_start_before dev2_start dev4_start devnulls_start

Writes `experiments/results/diagnose_nested_start.md` (one table per tag; `restarted` is the
diagnosis's `localisation.restarted_zones`: mechanism -> zones refitted from the nearly-off start;
`-` for results made before the restarts existed)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def table(tag: str) -> list[str]:
    d = json.loads((RESULTS / f"diagnose_heldout_hard_{tag}.json").read_text())
    m = d["meta"]
    out = [f"## {tag}", "", f"CPU s {m.get('cpu_s', float('nan')):.0f}, load {m.get('load')}", "",
           "| case | top | counted | confidence | rivals | gain pts | restarted | candidates with LR < 0 |",
           "|---|---|---|---|---|---|---|---|"]
    for r in d["records"]:
        neg = {x["mechanism"]: round(x["estimation_lr"], 1) for x in r["candidates"] if x["estimation_lr"] < -0.05}
        conf = "" if r["confidence"] is None else f"{r['confidence']:.3f}"
        out.append(f"| {r['case']} | {r['top']} | {'ok' if r['correct'] else 'MISS'} | {conf} | "
                   f"{', '.join(r['rivals'])} | {r['gain']:.2f} | {r.get('restarted_zones', '-')} | {neg} |")
    return out + [""]


def main(tags):
    lines = ["# Nested restarts (issue 14): development sets", "",
             f"Made by `python experiments/diagnose_nested_start_table.py {' '.join(tags)}`.", ""]
    for t in tags:
        if (RESULTS / f"diagnose_heldout_hard_{t}.json").exists():
            lines += table(t)
    (RESULTS / "diagnose_nested_start.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main(sys.argv[1:])
