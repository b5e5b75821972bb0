"""Baseline validation fits with the surroundings level per zone or shared (issue 14).

Without a measured surroundings signal every zone's baseline is fitted with its own level offset
(`ts0`); the validation simulation (`mechanisms.simulate_full`) used to give all zones one shared
level, the median of those offsets. This script runs the diagnosis's baseline on records whose
level is free (the harder held-out study's development cases without a measured surroundings
column, and the real recordings) and writes the baseline's validation fit and SAE. Run it once
with the code before the change (`PYTHONPATH=<old tree>`) and once after, with `--tag`:

    .venv/bin/python experiments/diagnose_zone_levels.py --tag after
    PYTHONPATH=/path/to/old python experiments/diagnose_zone_levels.py --tag before

Only the baseline is wanted: the one candidate tried is `recoat_cooling` (no periodic events, no
finding), so no augmented model is fitted. Writes
`experiments/results/diagnose_zone_levels_<tag>.{md,json}`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)


import jthermo
from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose, to_json

sys.path.insert(0, str(Path(__file__).resolve().parent))
from diagnose_heldout_hard import KINDS, draw_case, make_record
from diagnose_real import PAIRS, _load_pair

ROOT = Path(__file__).resolve().parents[1]
#: harder held-out development cases (seed set 0, --max-zones 6) without a measured surroundings column
HARD_CASES = (0, 2, 5, 6, 12, 13, 15, 18)
REAL_ROWS = ("tclab_cace2020 2 heaters", "tclab_cace2020 1 heater", "tclab_apm_mimo_steps",
             "tclab_dowling sine 5 min")


def _cpu():
    t = os.times()
    return t.user + t.system


def records(which, cases=HARD_CASES):
    for i in cases:
        if "hard" in which:
            c = draw_case(i, KINDS[i % len(KINDS)], 6)
            if not c["measured_ambient"]:
                yield f"hard {i:02d}_{c['kind']} N{c['zones']}", *make_record(c)
    for name, est_rel, val_rel, _, _ in PAIRS:
        if "real" in which and name in REAL_ROWS:
            yield name, *_load_pair(est_rel, val_rel)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--tag", required=True)
    ap.add_argument("--which", default="hard,real")
    ap.add_argument("--cases", default=",".join(map(str, HARD_CASES)), help="hard cases to run")
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    rows = []
    code = str(Path(jthermo.__file__).resolve().parent)
    for name, est, val in records(args.which, [int(v) for v in args.cases.split(",")]):
        t0, c0 = time.perf_counter(), _cpu()
        res = to_json(diagnose(est, val, mechanisms=("recoat_cooling",)))
        b = res["baseline"]
        rows.append({"record": name, "fit_percent": b["fit_percent"], "mean_fit_percent": b["mean_fit_percent"],
                     "sae": b["sum_abs_error"], "wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0,
                     "load": os.getloadavg()[0]})
        print(name, [round(v, 2) for v in b["fit_percent"]], flush=True)
        meta = {"tag": args.tag, "code": "checkout" if code == str(ROOT / "jthermo") else "other tree"}
        atomic_write_text(out / f"diagnose_zone_levels_{args.tag}.json",
                          json.dumps({"meta": meta, "rows": rows}, indent=1, default=float))
        lines = [f"# Baseline validation fits, surroundings level: {args.tag}", "",
                 f"Made by `python experiments/diagnose_zone_levels.py {' '.join(argv or sys.argv[1:])}` "
                 f"({meta['code']}).", "",
                 "| record | fit % per zone | mean fit % | SAE | wall s (CPU s, load) |", "|---|---|---|---|---|"]
        lines += [f"| {r['record']} | {'/'.join(f'{v:.1f}' for v in r['fit_percent'])} | "
                  f"{r['mean_fit_percent']:.2f} | {r['sae']:.1f} | {r['wall_s']:.0f} ({r['cpu_s']:.0f}, "
                  f"{r['load']:.1f}) |" for r in rows]
        atomic_write_text(out / f"diagnose_zone_levels_{args.tag}.md", "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
