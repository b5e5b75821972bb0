"""Chosen development cases of the harder study (cases a change was checked on), each
diagnosed once, one line each: a quick A/B of a change on the cases it is meant to move and on those it could break.

    .venv/bin/python experiments/diagnose_heldout_cases.py 14:9 9:8 ... [--max-zones 3]

A case is `CASE:SET` (`diagnose_heldout_hard.draw_case(CASE, seed_set=SET)`, records as that
script makes them today). Writes `experiments/results/diagnose_heldout_cases.md`: the top
finding and whether it counts as right (`diagnose_heldout_hard.COUNTED`), its rivals, the
candidates flagged, the augmented model, the surroundings-drift agreement figures (the zones'
own drifts against the common one: likelihood ratios, `decide.drift_contradicted`) and the CPU
seconds of each diagnosis.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H


def one(case: int, seed_set: int, max_zones: int) -> dict:
    c = H.draw_case(case, None, max_zones, seed_set)
    est, val = H.make_record(c)
    c0 = sum(os.times()[:2])
    r = diagnose(est, val)
    loc = r["localisation"]
    top = r["findings"][0]["mechanism"] if r["findings"] else None
    counted = H.COUNTED[c["kind"]]
    return {"case": f"{case:02d}:{seed_set}", "kind": c["kind"], "zones": c["zones"], "top": top,
            "right": (top in counted) if counted else top is None,
            "rivals": r["findings"][0]["rivals"] if r["findings"] else [],
            "flagged": [f["mechanism"] for f in r["flagged"]], "augmented": r["augmented"]["mechanisms"],
            "own_vs_common_lr": [round(v, 1) for v in loc.get("drift_own_vs_common_lr", [])],
            "agreement_z": loc.get("drift_agreement_z"), "cpu_s": sum(os.times()[:2]) - c0}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+", help="CASE:SET")
    ap.add_argument("--max-zones", type=int, default=3)
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows = []
    for spec in args.cases:
        case, seed_set = (int(v) for v in spec.split(":"))
        rows.append(one(case, seed_set, args.max_zones))
        jax.clear_caches()          # compiled code's memory maps would pile up (heldout_hard)
        print(rows[-1], flush=True)
    fmt = lambda v: "-" if v in (None, []) else (", ".join(v) if isinstance(v, list) and v and isinstance(v[0], str)
                                                 else str(v))
    lines = ["# Development cases, one line each", "",
             (f"Made by `python experiments/diagnose_heldout_cases.py {' '.join(args.cases)} --max-zones "
             f"{args.max_zones}`: {sum(r['right'] for r in rows)}/{len(rows)} right; "
             f"wall {time.perf_counter() - t0:.0f} s, 1-min load {os.getloadavg()[0]:.1f} at the end."), "",
             ("| case:set | kind | N | named | right | rivals | flagged | augmented | own vs common drift LR "
             "| drift agreement z | CPU s |"), "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        z = "-" if r["agreement_z"] is None else f"{r['agreement_z']:.2f}"
        lines.append(f"| {r['case']} | {r['kind']} | {r['zones']} | {fmt(r['top'])} | {'yes' if r['right'] else 'no'} | "
                     f"{fmt(r['rivals'])} | {fmt(r['flagged'])} | {fmt(r['augmented'])} | "
                     f"{fmt(r['own_vs_common_lr'])} | {z} | {r['cpu_s']:.0f} |")
    atomic_write_text(Path(args.out) / "diagnose_heldout_cases.md", "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
