"""Whether two runs of `diagnose_heldout_hard.py` gave the same answers, case by case: the names
and rivals, the top confidence, the augmented fit, the candidates' estimation LRs (largest
relative difference) and the CPU seconds.

    python experiments/diagnose_heldout_same.py --a s33_mz9_set12_iter200 --b h34speed_set12

Writes `experiments/results/diagnose_heldout_same_{a}_vs_{b}.md`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

RES = Path(__file__).resolve().parent / "results"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--a", required=True)
    ap.add_argument("--b", required=True)
    args = ap.parse_args(argv)
    a, b = (json.loads((RES / f"diagnose_heldout_hard_{t}.json").read_text()) for t in (args.a, args.b))
    ra = {r["case"]: r for r in a["records"]}
    L = [f"# Same answers? {args.a} vs {args.b}", "",
         f"`python experiments/diagnose_heldout_same.py --a {args.a} --b {args.b}`", "",
         "| case | same names | same rivals | top confidence diff | augmented fit % a / b | max rel. LR diff | CPU s a -> b |",
         "|---|---|---|---|---|---|---|"]
    n_same = 0
    for r in b["records"]:
        x = ra[r["case"]]
        key = lambda c: c["mechanism"]
        lr = max((abs(p["estimation_lr"] - q["estimation_lr"]) / max(1.0, abs(p["estimation_lr"]))
                  for p, q in zip(sorted(x["candidates"], key=key), sorted(r["candidates"], key=key))), default=0.0)
        dc = "-" if x["confidence"] is None else f"{abs(x['confidence'] - r['confidence']):.1e}"
        same = x["named"] == r["named"] and x["rivals"] == r["rivals"]
        n_same += same
        L.append(f"| {r['case']} | {x['named'] == r['named']} | {x['rivals'] == r['rivals']} | {dc} | "
                 f"{x['augmented_fit']:.4f} / {r['augmented_fit']:.4f} | {lr:.1e} | {x['cpu_s']:.0f} -> {r['cpu_s']:.0f} |")
    L += ["", (f"{n_same}/{len(b['records'])} cases name the same mechanisms with the same rivals; run CPU s "
               f"{a['meta']['cpu_s']:.0f} -> {b['meta']['cpu_s']:.0f} (loads at the end: {a['meta']['load']} / "
               f"{b['meta']['load']}).")]
    out = RES / f"diagnose_heldout_same_{args.a}_vs_{args.b}.md"
    out.write_text("\n".join(L) + "\n")
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
