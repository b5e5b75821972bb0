"""Recoat drops at irregular times: does the diagnosis name `recoat_cooling`?

Real recoats come once per layer, spaced by each layer's scan time, which follows the part's
cross-section: the drops do not come at a fixed period. The records are the harder held-out
study's plant (`diagnose_heldout_hard.py`, kind `recoat_irregular`: spacing 30-300 s, drawn anew
for every layer or wandering slowly, at any fraction of a sample; each zone its own drop
0.3-2 °C, every layer 0.7-1.3 times it; a sweep over the zones within 0-10 s; N = 1..4 zones,
Ts = 0.3-5 s, white + AR(2) noise 0.02-0.12 °C), drawn from seeds of their own
(`SeedSequence([i, 2026, 1414, 14, 99])`, no held-out set's).

    .venv/bin/python experiments/diagnose_recoat_irregular.py [--cases 12]
    PYTHONPATH=/tmp/base .venv/bin/python experiments/diagnose_recoat_irregular.py

Writes `experiments/results/diagnose_recoat_irregular.{md,json}` (after every case): per
record the truth (events, gap range, drops / noise), what was named, the fit gain, the drop
statistic against its level, and CPU seconds; `--compare A.json,B.json` puts two runs' JSON side
by side in `diagnose_recoat_irregular_compare.md`.
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

import numpy as np

import jthermo
from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose, to_json

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H

OUT = Path(__file__).resolve().parent / "results"


def seq(i: int) -> np.random.SeedSequence:
    return np.random.SeedSequence([i, 2026, 1414, 14, 99])


def cpu_s():
    t = os.times()
    return t.user + t.system


def run(args):
    rows = []
    path = OUT / "diagnose_recoat_irregular"
    for i in range(args.first, args.first + args.cases):
        c = H.draw_case(i, "recoat_irregular", args.max_zones, seq=seq(i))
        est, val = H.make_record(c)
        t1, c1 = time.perf_counter(), cpu_s()
        res = to_json(diagnose(est, val))
        named = [f["mechanism"] for f in res["findings"]]
        drops = res["localisation"].get("drops", {})
        per = res["localisation"]["periodic"]
        rows.append({"case": i, "zones": c["zones"], "ts": round(c["ts"], 3), "noise_C": round(c["noise"], 3),
                     "physics": H.describe(c), "named": named, "top": named[0] if named else None,
                     "correct": bool(named and named[0] == "recoat_cooling"),
                     "baseline_fit": res["baseline"]["mean_fit_percent"],
                     "augmented_fit": res["augmented"]["mean_fit_percent"],
                     "gain": res["augmented"]["mean_fit_percent"] - res["baseline"]["mean_fit_percent"],
                     "periodic": per, "drops": drops,
                     "recoat": next((r for r in res["candidates"] if r["mechanism"] == "recoat_cooling"), None),
                     "seconds": time.perf_counter() - t1, "cpu_s": cpu_s() - c1})
        r = rows[-1]
        print(f"{i:02d} N{c['zones']} Ts{c['ts']:.2f}: {r['top']} ({'ok' if r['correct'] else 'MISS'}) gain "
              f"{r['gain']:.2f}, drops {drops.get('statistic', float('nan')):.1f}/{drops.get('level', float('nan')):.1f}"
              f" ({drops.get('events', 0)} events), {r['cpu_s']:.0f} s cpu, load {os.getloadavg()[0]:.1f}",
              flush=True)
        write(rows, args, path)
    return rows


def write(rows, args, path):
    ok = sum(r["correct"] for r in rows)
    meta = {"args": f"--cases {args.cases} --first {args.first} --max-zones {args.max_zones}",
            "jthermo": os.path.relpath(Path(jthermo.__file__).parent), "load": " ".join(f"{v:.2f}" for v in os.getloadavg()),
            "cpu_s": sum(r["cpu_s"] for r in rows)}
    atomic_write_text(path.with_suffix(".json"), json.dumps({"meta": meta, "top1": [ok, len(rows)], "records": rows},
                                                            indent=1, default=float))
    lines = ["# Irregular recoat drops", "",
             (f"Made by `python experiments/diagnose_recoat_irregular.py {meta['args']}` (jthermo from "
              f"`{meta['jthermo']}`; load {meta['load']})."), "",
             f"**top-1 `recoat_cooling`: {ok}/{len(rows)}**; CPU {meta['cpu_s']:.0f} s (user+sys) in all.", "",
             ("| case | N | Ts s | noise °C | events | gaps s | spacing | drops °C | sweep s | named | fit base → aug % | "
              "drop stat / level | periodic stat | recoat z, LR | cpu s |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        p, d, rc = r["physics"], r["drops"], r["recoat"] or {}
        lines.append(f"| {r['case']:02d} | {r['zones']} | {r['ts']} | {r['noise_C']} | {p['events']} | {p['gap_s']} | "
                     f"{p['spacing']} | {p['drops_C']} | {p['sweep_s']} | {', '.join(r['named']) or '—'} | "
                     f"{r['baseline_fit']:.2f} → {r['augmented_fit']:.2f} | "
                     f"{d.get('statistic', float('nan')):.1f} / {d.get('level', float('nan')):.1f} | "
                     f"{r['periodic']['statistic']:.1f} | {rc.get('validation_z', float('nan')):.2f}, "
                     f"{rc.get('estimation_lr', float('nan')):.0f} | {r['cpu_s']:.0f} |")
    atomic_write_text(path.with_suffix(".md"), "\n".join(lines) + "\n")


def compare(paths):
    data = [json.loads(Path(t).read_text()) for t in paths]
    tags = [Path(t).stem for t in paths]
    lines = [f"# Irregular recoat drops: {' vs '.join(tags)}", "",
             f"Made by `python experiments/diagnose_recoat_irregular.py --compare {','.join(paths)}`.", "",
             "| " + " | ".join(f"{t}: top-1" for t in tags) + " | " + " | ".join(f"{t}: CPU s" for t in tags) + " |",
             "|" + "---|" * (2 * len(tags)),
             "| " + " | ".join(f"{d['top1'][0]}/{d['top1'][1]}" for d in data) + " | "
             + " | ".join(f"{d['meta']['cpu_s']:.0f}" for d in data) + " |", "",
             "| case | " + " | ".join(f"{t}: named (gain)" for t in tags) + " |", "|---|" + "---|" * len(tags)]
    for k in range(min(len(d["records"]) for d in data)):
        lines.append(f"| {data[0]['records'][k]['case']:02d} | " + " | ".join(
            f"{', '.join(d['records'][k]['named']) or '—'} ({d['records'][k]['gain']:.2f})" for d in data) + " |")
    atomic_write_text(OUT / "diagnose_recoat_irregular_compare.md", "\n".join(lines) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", type=int, default=12)
    ap.add_argument("--first", type=int, default=0)
    ap.add_argument("--max-zones", type=int, default=4)
    ap.add_argument("--compare", default=None, metavar="JSONS")
    args = ap.parse_args(argv)
    if args.compare:
        compare(args.compare.split(","))
        return 0
    run(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
