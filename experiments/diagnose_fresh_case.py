"""One case of the loop's development set (`diagnose_fresh_loop.py`, seed tag 1) in detail: why a
finding is named, with what confidence, alone and with the designed experiment pooled.

That set was scored once at its commit; its cases 03, 05 and 08 (confident wrong names) were
then studied here and the diagnosis changed on them, so from then on it is a *development* set
(`diagnose_heldout_scoreboard.py` lists it so): a score of the changed code needs new seeds.

    .venv/bin/python experiments/diagnose_fresh_case.py --case 5 [--max-zones 4] [--experiment-s 3600]

Per case: the records of `diagnose_fresh_loop.py` (the same seed, plant and runner), the
diagnosis alone, the designed experiment run on the true plant and the pooled diagnosis
(`diagnose_loop`, one experiment at most), and for each round every candidate's tests, the
slow body / drift statistics of the localisation report, the findings with their confidence
and rivals, and each pooled record's share of the evidence. Writes
`experiments/results/diagnose_fresh_case.{md,json}`: one section per case studied, a rerun of a
case replacing its section.
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

from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose_loop

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_fresh_loop as F  # patches the drift's surroundings of `H`
import diagnose_heldout_hard as H

#: the localisation report's figures on the slow body and the drift
SLOW_KEYS = ("drift_input_dependence_records_z", "drift_input_dependence_z", "drift_over_body_z",
             "drift_over_body_estimation_z", "drift_agreement_z", "runner")


def round_of(res: dict) -> dict:
    """The figures of one diagnosis that say why its findings are named as they are."""
    loc = res.get("localisation") or {}
    return {"findings": [{"mechanism": f["mechanism"], "confidence": f["confidence"], "rivals": f["rivals"],
                          "uncertain": f["uncertain"],
                          "records": f["evidence"].get("records")} for f in res["findings"]],
            "slow": {k: loc[k] for k in SLOW_KEYS if k in loc},
            "candidates": [{k: r[k] for k in ("mechanism", "validation_z", "validation_z_critical",
                                              "estimation_lr", "estimation_lr_critical", "significant",
                                              "val_reduction")} for r in res["candidates"]],
            "combinations": [{k: a.get(k) for k in ("mechanisms", "validation_z", "estimation_lr", "passed",
                                                    "accepted", "rivals", "z_over_runner")}
                             for a in res.get("combinations") or []]}


def study(i: int, max_zones: int, experiment_s: float, seed_tag: int, keep_records: str | None = None) -> dict:
    kind = F.PLAN[i]
    c = H.draw_case(i, kind, max_zones, seq=F.case_seed(i, seed_tag))
    est, val = H.make_record(c)
    calls: list = []
    run0 = F.plant_runner(c, (est.input_names, est.output_names), calls)
    ran: list = []

    def run(u):
        ran.append(run0(u))
        return ran[-1]

    rounds = []
    t0, c0 = time.perf_counter(), H.cpu_s()
    import jthermo.diagnose.loop as L
    diagnose0 = L.diagnose

    def keep(*a, **k):        # every round's full report, not only the loop's summary
        res = diagnose0(*a, **k)
        rounds.append(round_of(res))
        return res

    L.diagnose = keep
    try:
        loop = diagnose_loop(est, val, run, max_experiments=1,
                             duration=int(min(round(experiment_s / c["ts"]), H.MAX_EST)))
    finally:
        L.diagnose = diagnose0
    if keep_records:          # the records, to study the pooled diagnosis without the loop
        import pickle
        Path(keep_records).write_bytes(pickle.dumps({"est": est, "val": val, "more": ran}))
    return {"case": f"{i:02d}_{kind}", "kind": kind, "zones": c["zones"], "ts": c["ts"],
            "physics": H.describe(c), "counted": list(H.COUNTED[kind]),
            "scores": [F.score(r["findings"], kind) for r in loop["rounds"]], "rounds": rounds,
            "experiment_s": sum(calls) * c["ts"], "cpu_s": H.cpu_s() - c0, "wall_s": time.perf_counter() - t0}


def lines_of(r: dict) -> list[str]:
    out = [f"## Case {r['case']}", "",
           (f"N = {r['zones']}, Ts = {r['ts']:.2f} s, physics {json.dumps(r['physics'])}, counted as "
            f"{', '.join(r['counted']) or 'nothing'}; experiment {r['experiment_s']:.0f} s; "
            f"{r['cpu_s']:.0f} CPU s, {r['wall_s']:.0f} s wall."), ""]
    for j, (rd, sc) in enumerate(zip(r["rounds"], r["scores"])):
        named = ", ".join(f"{f['mechanism']} {f['confidence']:.3f}"
                          + (f" (rivals {', '.join(f['rivals'])})" if f["rivals"] else "") for f in rd["findings"])
        wrong = ", ".join(sc["confident_wrong"]) or "none"
        out += [f"### {'Alone' if j == 0 else 'With the experiment pooled'}", "",
                f"- named: {named or 'nothing'}; top right {sc['correct']}; wrong at >= {F.CONFIDENT}: {wrong}",
                f"- slow body / drift: {json.dumps(rd['slow'], default=float)}"]
        for f in rd["findings"]:
            if f["records"]:
                out.append(f"- {f['mechanism']} per record: {json.dumps(f['records'])}")
        out += ["", "| candidate | validation z / critical | estimation LR / critical | significant | val. MSE reduction |",
                "|---|---|---|---|---|"]
        out += [f"| {x['mechanism']} | {x['validation_z']:.2f} / {x['validation_z_critical']:.2f} | "
                f"{x['estimation_lr']:.1f} / {x['estimation_lr_critical']:.1f} | {x['significant']} | "
                f"{x['val_reduction']:.4f} |" for x in rd["candidates"]]
        acc = [a for a in rd["combinations"] if a["accepted"]]
        if acc:
            out += ["", "Additions accepted: " + "; ".join(
                f"{'+'.join(a['mechanisms'])} (validation z {a['validation_z']:.2f}, LR {a['estimation_lr']:.1f}, "
                f"rivals {a.get('rivals') or '-'})" for a in acc)]
        out.append("")
    return out


def render(stored: dict, out: Path):
    """`diagnose_fresh_case.md` from the stored JSON: every case studied, in case order."""
    lines = ["# Development cases of the loop's set in detail", "",
             "The set of `diagnose_fresh_loop.py` (seed tag 1) was scored once; the cases below were then",
             "studied and the diagnosis changed on them, so it is a development set from then on.", ""]
    for k in sorted(stored["cases"]):
        x = stored["cases"][k]
        lines += [(f"Made by `python experiments/diagnose_fresh_case.py {x['args']}` at commit "
                   f"`{x['commit']}` (load {x['load']}, under `nice -n 10`)."), ""] + lines_of(x)
    atomic_write_text(out / "diagnose_fresh_case.md", "\n".join(lines) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", type=int, default=None)
    ap.add_argument("--max-zones", type=int, default=4)
    ap.add_argument("--experiment-s", type=float, default=3600.0)
    ap.add_argument("--seed-tag", type=int, default=1)
    ap.add_argument("--out", default="experiments/results")
    ap.add_argument("--keep-records", default=None, help="pickle the case's records to this path")
    ap.add_argument("--render", action="store_true",
                    help="only write the tables again from the stored JSON (nothing is diagnosed)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    path = out / "diagnose_fresh_case.json"
    if args.render:
        render(json.loads(path.read_text()), out)
        return 0
    if args.case is None or not 0 <= args.case < len(F.PLAN):
        print(f"jthermo: error: --case must be 0..{len(F.PLAN) - 1}", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    r = study(args.case, args.max_zones, args.experiment_s, args.seed_tag, args.keep_records)
    stored = json.loads(path.read_text()) if path.exists() else {"cases": {}}
    r["commit"] = H.commit()
    r["args"] = f"--case {args.case} --max-zones {args.max_zones} --experiment-s {args.experiment_s:g} --seed-tag {args.seed_tag}"
    r["load"] = " ".join(f"{v:.2f}" for v in os.getloadavg())
    stored["cases"][r["case"]] = r
    atomic_write_text(path, json.dumps(stored, indent=1, default=float))
    render(stored, out)
    print("\n".join(lines_of(r)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
