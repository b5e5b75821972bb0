"""Pooled estimation records on real recordings: is a finding from two records of one kit at
least as sure as from either alone, and does the single-record CACE 2020 check still hold?

For each group, the diagnosis is run on each estimation record alone and on the records pooled
(`diagnose([a, b], val)`: shared physical parameters, each record its own initial state,
surroundings level and drift), all validated on the same record. The table gives the top
finding, its confidence and rivals, the estimation likelihood ratio of the top mechanism, each
pooled record's share of its evidence, the validation SAE (sum of absolute errors, the CACE 2020
paper's metric) and any crash.

    .venv/bin/python experiments/diagnose_pooled_real.py [--only NAME]

Writes `experiments/results/diagnose_pooled_real.md` and `.json` (overwritten when rerun).
"""

from __future__ import annotations

import argparse
import json
import time
import traceback
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from jthermo.data import atomic_write_text, load  # noqa: E402
from jthermo.diagnose import diagnose, to_json  # noqa: E402
from jthermo.errors import JThermoError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: `../shared/data/real` beside the checkout (or beside a folder above it: a worktree)
REAL = next((p / "shared" / "data" / "real" for p in ROOT.parents if (p / "shared" / "data" / "real").is_dir()),
            ROOT.parent / "shared" / "data" / "real")

#: (name, estimation records, validation record, actuator, published validation SAE or None)
GROUPS = [
    ("tclab_cace2020 2 heaters", ["tclab_cace2020/id_2heaters"], "tclab_cace2020/val_2heaters",
     "resistive-pwm", 840.95),
    ("tclab_dowling sine 5 min", ["tclab_dowling_pyomo_doe/sine_5min_run1", "tclab_dowling_pyomo_doe/sine_5min_run2"],
     "tclab_dowling_pyomo_doe/sine_5min_run3", "resistive-pwm", None),
    ("tclab_kantor steps", ["tclab_kantor_cbe30338/step_q1_50_b", "tclab_kantor_cbe30338/step_q1_50_c"],
     "tclab_kantor_cbe30338/step_q1_50_a", "resistive-pwm", None),
]


def _load(rel):
    p = REAL / rel
    return load(p / "data.csv" if p.is_dir() else p)


def _row(label, ests, val, actuator):
    t0 = time.perf_counter()
    try:
        res = to_json(diagnose(ests if len(ests) > 1 else ests[0], val, actuator=actuator))
    except JThermoError as e:
        return {"run": label, "error": f"{type(e).__name__}: {e}", "crash": False}
    except Exception:                                   # noqa: BLE001  a crash is a finding here
        return {"run": label, "error": traceback.format_exc(limit=3), "crash": True}
    top = res["findings"][0] if res["findings"] else None
    lr = (next(c["estimation_lr"] for c in res["candidates"] if c["mechanism"] == top["mechanism"])
          if top else None)
    return {"run": label, "crash": False, "top": top["mechanism"] if top else None,
            "confidence": top["confidence"] if top else None, "rivals": top["rivals"] if top else [],
            "estimation_lr": lr, "shares": [s["sse_share"] for s in top["evidence"].get("records", [])] if top else [],
            "augmented": res["augmented"]["mechanisms"], "sae": res["augmented"]["sum_abs_error"],
            "fit": res["augmented"]["mean_fit_percent"], "seconds": time.perf_counter() - t0}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="run only the group whose name contains this")
    args = ap.parse_args(argv)
    rows = []
    for name, est_rel, val_rel, actuator, sae_pub in GROUPS:
        if args.only and args.only not in name:
            continue
        ests, val = [_load(r) for r in est_rel], _load(val_rel)
        runs = [(Path(r).name, [e]) for r, e in zip(est_rel, ests)]
        if len(ests) > 1:
            runs.append(("pooled", ests))
        for label, es in runs:
            r = _row(label, es, val, actuator)
            rows.append({"group": name, "validation": Path(val_rel).name, "published_sae": sae_pub, **r})
            print(json.dumps(rows[-1], default=float), flush=True)
    out = ROOT / "experiments" / "results"
    atomic_write_text(out / "diagnose_pooled_real.json", json.dumps(rows, indent=1, default=float))
    lines = ["# Pooled estimation records on real recordings", "",
             "Made by `python experiments/diagnose_pooled_real.py` (measured on a shared, loaded machine: "
             "seconds are wall time under load).", "",
             "| group | estimation | validation | top (confidence) | rivals | LR of top | record shares | "
             "augmented | fit % | SAE (published) | s |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['group']} | {r['run']} | {r['validation']} | {'CRASH' if r['crash'] else 'refused'}: "
                         f"{r['error'].splitlines()[-1][:120]} | | | | | | | |")
            continue
        top = f"`{r['top']}` ({r['confidence']:.3f})" if r["top"] else "none"
        lr = f"{r['estimation_lr']:.1f}" if r["estimation_lr"] is not None else ""
        pub = f" ({r['published_sae']:.2f})" if r["published_sae"] else ""
        lines.append(f"| {r['group']} | {r['run']} | {r['validation']} | {top} | {', '.join(r['rivals'])} | {lr} | "
                     f"{', '.join(f'{s:.2f}' for s in r['shares'])} | {' + '.join(r['augmented'])} | "
                     f"{r['fit']:.1f} | {r['sae']:.1f}{pub} | {r['seconds']:.0f} |")
    atomic_write_text(out / "diagnose_pooled_real.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
