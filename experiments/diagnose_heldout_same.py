"""Whether two runs of `diagnose_heldout_hard.py` gave the same answers, case by case: the names
and rivals, the top confidence, the augmented fit, the candidates' estimation LRs (largest
relative difference) and the CPU seconds.

    python experiments/diagnose_heldout_same.py --a A/diagnose_heldout_hard.json --b B/diagnose_heldout_hard.json
    python experiments/diagnose_heldout_same.py --real --a DIR_A/diagnose_real.json --b DIR_B/diagnose_real.json

Writes `experiments/results/diagnose_heldout_same.md`; with `--real` the two `diagnose_real.py`
JSON files are compared: names, flagged, each finding's confidence, fits and SAE.
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
    ap.add_argument("--real", action="store_true")
    args = ap.parse_args(argv)
    if args.real:
        return real(args.a, args.b)
    a, b = (json.loads(Path(t).read_text()) for t in (args.a, args.b))
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
    out = RES / "diagnose_heldout_same.md"
    out.write_text("\n".join(L) + "\n")
    print("\n".join(L))
    return 0


def real(ta: str, tb: str) -> int:
    a, b = ({r["data"]: r for r in json.loads(Path(t).read_text())} for t in (ta, tb))
    L = [f"# Same answers? {ta} vs {tb}", "",
         f"`python experiments/diagnose_heldout_same.py --real --a {ta} --b {tb}`", "",
         "| data | status | named a / b | flagged a / b | max confidence diff | fit % a / b | SAE a / b | CPU s a -> b |",
         "|---|---|---|---|---|---|---|---|"]
    n_same = 0
    for name, y in b.items():
        x = a.get(name, {})
        conf = lambda r: [f["confidence"] for f in r.get("findings", [])]
        dc = max((abs(p - q) for p, q in zip(conf(x), conf(y))), default=0.0)
        fit = lambda r: "/".join(f"{v:.2f}" for v in r.get("augmented_fit", []))
        sae = lambda r: f"{r['augmented_sae']:.2f}" if "augmented_sae" in r else "-"
        same = (x.get("named") == y.get("named") and x.get("flagged") == y.get("flagged")
                and x.get("status") == y.get("status") and dc < 1e-3 and fit(x) == fit(y) and sae(x) == sae(y))
        n_same += same
        L.append(f"| {name} | {y['status'][:30]} | {x.get('named')} / {y.get('named')} | {x.get('flagged')} / "
                 f"{y.get('flagged')} | {dc:.1e} | {fit(x)} / {fit(y)} | {sae(x)} / {sae(y)} | "
                 f"{x.get('cpu_seconds', float('nan')):.0f} -> {y.get('cpu_seconds', float('nan')):.0f} |")
    L += ["", f"{n_same}/{len(b)} records: same status, names, flagged, confidences (to 1e-3), fits and SAE (to 0.01)."]
    (RES / "diagnose_heldout_same.md").write_text("\n".join(L) + "\n")
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
