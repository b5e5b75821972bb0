"""Radiation's extra fit starts (`mechanisms.rad_starts`) on held-out convection and lamp cases.

Held-out natural convection ($c\\Delta^{4/3}$, `diagnose_heldout_hard.py` kind `convection_hT`,
counted right as `radiative_loss`) was named `input_nonlinearity`, twice with confidence 0.999.
On set 11 case 02 the per-zone radiative fit of zone 2 stopped at `N_ITER` = 60 iterations with a
share of 1.18 of the tangent loss, on its way from the neutral start's 0.5 to the 1.75 that 300
iterations (or a start at 3.0) reach with a lower estimation cost; its validation MSE reduction
then rises from 0.9535 to 0.9769, above the lamp exponent's 0.9749. This script diagnoses each
case twice in one process, interleaved: without the extra starts (`RAD_SHARE_STARTS = ()`, the
code before) and with them (each zone keeps the start of smallest estimation cost), and
reports per case what was named (confidence, rivals), radiation's and the lamp exponent's
validation MSE reduction and the per-zone radiative shares.

Cases are `CASE:SET` of the development seed sets (1-11; set 12 and above are the lead's
scoring sets and are refused), or `--kind K --sets 1-11` for the study's cases of kind K (cases
2 and 17 for `convection_hT`, 8 for `lamp_saturation`), at `--max-zones` 3.

    .venv/bin/python experiments/diagnose_rad_starts.py --kind convection_hT --sets 1-11 --tag conv
    .venv/bin/python experiments/diagnose_rad_starts.py --kind lamp_saturation --sets 1-11 --tag lamp

    .venv/bin/python experiments/diagnose_rad_starts.py --merge conv_1_7,conv_8_11,lamp_1_11 --tag s32
    .venv/bin/python experiments/diagnose_rad_starts.py --tag _s32_radstarts_before \
        --study-without-starts "--only nonlinearity_1.5,nonlinearity_0.7,radiation,radiation_strong,radiation_noisy_7 --no-real"

Writes `experiments/results/diagnose_rad_starts_<tag>.{md,json}` after every case (`--merge`: the
rows of earlier runs in one table).
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

from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose
from jthermo.diagnose import mechanisms as M
from jthermo.diagnose.select import N_ITER

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H

ROOT = Path(__file__).resolve().parents[1]
#: the first seed set the lead keeps for scoring: never diagnosed here
SCORING_SET = 12
VARIANTS = {"before": (), "after": M.RAD_SHARE_STARTS}


def parse_sets(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def one(c, starts) -> dict:
    """Diagnose case `c` with radiation's extra starts `starts`; the figures reported."""
    M.RAD_SHARE_STARTS = starts
    est, val = H.make_record(c)
    c0, t0 = os.times(), time.perf_counter()
    r = diagnose(est, val)
    cpu = sum(os.times()[:2]) - sum(c0[:2])
    cand = {x["mechanism"]: x for x in r["candidates"]}
    lay = r["_models"]["layout"]
    th = r["_models"]["theta"]["radiative_loss"]
    share = M.RAD_SHARE_MAX / (1.0 + np.exp(-th[:, lay.sl("rad_share")][:, 0]))
    return {"named": [[f["mechanism"], round(f["confidence"], 3), f["rivals"]] for f in r["findings"]],
            "top": r["findings"][0]["mechanism"] if r["findings"] else None,
            "uncertain": bool(r["findings"][0]["uncertain"]) if r["findings"] else None,
            "fit": [round(r["baseline"]["mean_fit_percent"], 2), round(r["augmented"]["mean_fit_percent"], 2)],
            "rad_val_reduction": cand["radiative_loss"]["val_reduction"],
            "rad_significant": cand["radiative_loss"]["significant"],
            "unl_val_reduction": cand["input_nonlinearity"]["val_reduction"],
            "rad_share_per_zone": [round(float(v), 3) for v in share],
            "rad_est_sse_per_zone": [round(float(v), 4) for v in
                                     np.sum(r["_arrays"]["resid_est_candidates"]["radiative_loss"] ** 2, axis=0)],
            "cpu_s": round(cpu, 1), "wall_s": round(time.perf_counter() - t0, 1)}


def verdict(row, kind) -> str:
    top = row["top"]
    if top is None:
        return "nothing"
    ok = top in H.COUNTED[kind]
    return ("right" if ok else "WRONG") + (" (uncertain)" if row["uncertain"] else "")


def write(rows, tag, cmd):
    cols = ("| case:set | kind | N | named before (conf, rivals) | named after (conf, rivals) | "
            "rad val red. before → after | u^p val red. | rad shares before → after | CPU s before / after |")
    lines = [f"# Radiation's extra starts on held-out cases ({tag})", "", f"Made by `{cmd}` "
             f"(development seed sets only; before: `RAD_SHARE_STARTS = ()`, after: `RAD_SHARE_STARTS = {VARIANTS['after']}`; "
             f"interleaved per case in one process; 1-min load at the end {os.getloadavg()[0]:.1f}).", "",
             cols, "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        b, a = r["before"], r["after"]
        lines.append(f"| {r['case']:02d}:{r['set']} | {r['kind']} | {r['zones']} | {verdict(b, r['kind'])}: {b['named']} | "
                     f"{verdict(a, r['kind'])}: {a['named']} | {b['rad_val_reduction']:.4f} → {a['rad_val_reduction']:.4f} | "
                     f"{a['unl_val_reduction']:.4f} | {b['rad_share_per_zone']} → {a['rad_share_per_zone']} | "
                     f"{b['cpu_s']:.0f} / {a['cpu_s']:.0f} |")
    lines.append("\nCPU s: not a timing comparison: each case's 'before' runs first and compiles what the record's shapes need.")
    for kind in dict.fromkeys(r["kind"] for r in rows):
        for v in ("before", "after"):
            tally = {}
            for r in rows:
                if r["kind"] == kind:
                    k = verdict(r[v], kind)
                    tally[k] = tally.get(k, 0) + 1
            lines.append(f"\n{kind}, {v}: " + ", ".join(f"{k} {n}" for k, n in sorted(tally.items())))
    out = ROOT / "experiments" / "results" / f"diagnose_rad_starts_{tag}"
    atomic_write_text(out.with_suffix(".md"), "\n".join(lines) + "\n")
    atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1, default=float))


def timing(plan, max_zones, tag) -> int:
    """What the extra starts cost: each case diagnosed once per variant to compile, then
    before, after, after, before (interleaved), warm CPU seconds (user + sys) and the load."""
    lines = [f"# Cost of radiation's extra starts ({tag})", "",
             f"Made by `python experiments/diagnose_rad_starts.py {' '.join(f'{i}:{s}' for i, s in plan)} --timing "
             f"--tag {tag}` (warm: after one compiling run per variant).", "",
             "| case:set | N | warm CPU s before | warm CPU s after | 1-min load |", "|---|---|---|---|---|"]
    for i, s in plan:
        if s >= SCORING_SET:
            raise SystemExit(f"seed sets >= {SCORING_SET} are kept for scoring")
        c = H.draw_case(i, None, max_zones, s)
        cpu = {v: [] for v in VARIANTS}
        for v in ("before", "after", "before", "after", "after", "before"):
            cpu[v].append(one(c, VARIANTS[v])["cpu_s"])
        lines.append(f"| {i:02d}:{s} | {c['zones']} | {cpu['before'][1:]} | {cpu['after'][1:]} | {os.getloadavg()[0]:.1f} |")
        print(lines[-1], flush=True)
        atomic_write_text(ROOT / "experiments" / "results" / f"diagnose_rad_starts_{tag}.md", "\n".join(lines) + "\n")
    M.RAD_SHARE_STARTS = VARIANTS["after"]
    return 0


def iters_probe(plan, max_zones, tag, iters=(N_ITER, 300)) -> int:
    """Is the radiative fit converged at `N_ITER`? The diagnosis restricted to `radiative_loss` and
    `input_nonlinearity` (extra starts on) at each iteration cap in `iters`: validation MSEs,
    per-zone estimation SSE, shares, exponents and the z that the exponent predicts better."""
    from jthermo.diagnose import decide as D

    lines = [f"# Radiative and lamp-exponent fits at {iters[0]} and {iters[1]} iterations ({tag})", "",
             f"Made by `python experiments/diagnose_rad_starts.py {' '.join(f'{i}:{s}' for i, s in plan)} "
             f"--iters-probe --tag {tag}` (mechanisms restricted to the two; extra starts on).", "",
             "| case:set | iterations | val MSE base / rad / u^p | est SSE per zone rad | est SSE per zone u^p | "
             "rad shares | exponents | z u^p > rad |", "|---|---|---|---|---|---|---|---|"]
    for i, s in plan:
        if s >= SCORING_SET:
            raise SystemExit(f"seed sets >= {SCORING_SET} are kept for scoring")
        est, val = H.make_record(H.draw_case(i, None, max_zones, s))
        for it in iters:
            r = diagnose(est, val, mechanisms=("radiative_loss", "input_nonlinearity"), n_iter=it)
            ev, th, lay = r["_arrays"]["resid_val"], r["_models"]["theta"], r["_models"]["layout"]
            sse = {m: np.sum(r["_arrays"]["resid_est_candidates"][m] ** 2, axis=0).round(3).tolist()
                   for m in ("radiative_loss", "input_nonlinearity")}
            share = (M.RAD_SHARE_MAX / (1 + np.exp(-th["radiative_loss"][:, lay.sl("rad_share")][:, 0]))).round(3)
            e = np.exp(th["input_nonlinearity"][:, lay.sl("log_e")][:, 0]).round(3)
            mse = [float(np.mean(ev[m] ** 2)) for m in ("baseline", "radiative_loss", "input_nonlinearity")]
            z = D.predictive_z(ev["radiative_loss"], ev["input_nonlinearity"])
            lines.append(f"| {i:02d}:{s} | {it} | {' / '.join(f'{v:.5f}' for v in mse)} | {sse['radiative_loss']} | "
                         f"{sse['input_nonlinearity']} | {share.tolist()} | {e.tolist()} | {z:.2f} |")
            print(lines[-1], flush=True)
            atomic_write_text(ROOT / "experiments" / "results" / f"diagnose_rad_starts_{tag}.md", "\n".join(lines) + "\n")
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="*", help="CASE:SET pairs")
    ap.add_argument("--kind", default=None)
    ap.add_argument("--sets", default="1-11")
    ap.add_argument("--max-zones", type=int, default=3)
    ap.add_argument("--tag", required=True)
    ap.add_argument("--merge", default=None, help="comma-separated tags of earlier runs: one table of their rows")
    ap.add_argument("--study-without-starts", default=None, metavar="ARGS",
                    help="run `diagnose_study.py ARGS` with RAD_SHARE_STARTS = () (the code before)")
    ap.add_argument("--iters-probe", action="store_true",
                    help="the cases' radiative and lamp-exponent fits alone at N_ITER and at 300 iterations")
    ap.add_argument("--timing", action="store_true",
                    help="warm CPU s of each variant: one warm-up each, then before/after/after/before")
    args = ap.parse_args(argv)
    if args.timing:
        return timing([tuple(int(v) for v in s.split(":")) for s in args.cases], args.max_zones, args.tag)
    if args.iters_probe:
        return iters_probe([tuple(int(v) for v in s.split(":")) for s in args.cases], args.max_zones, args.tag)
    if args.study_without_starts is not None:
        import diagnose_study

        M.RAD_SHARE_STARTS = ()
        return diagnose_study.main(args.study_without_starts.split() + ["--tag", args.tag])
    cmd = "python experiments/diagnose_rad_starts.py " + " ".join(argv if argv is not None else sys.argv[1:])
    if args.merge:
        res = ROOT / "experiments" / "results"
        write([r for t in args.merge.split(",") for r in json.loads((res / f"diagnose_rad_starts_{t}.json").read_text())],
              args.tag, cmd)
        return 0
    plan = [tuple(int(v) for v in s.split(":")) for s in args.cases]
    if args.kind:
        idx = [i for i, k in enumerate(H.KINDS) if k == args.kind] or [2]
        plan += [(i, s) for s in parse_sets(args.sets) for i in idx]
    if any(s >= SCORING_SET for _, s in plan):
        raise SystemExit(f"seed sets >= {SCORING_SET} are kept for scoring")
    rows = []
    for i, s in plan:
        c = H.draw_case(i, args.kind if args.kind and H.KINDS[i % len(H.KINDS)] != args.kind else None,
                        args.max_zones, s)
        row = {"case": i, "set": s, "kind": c["kind"], "zones": c["zones"], "truth": H.describe(c)}
        for v, starts in VARIANTS.items():
            row[v] = one(c, starts)
        rows.append(row)
        print(json.dumps({k: row[k] for k in ("case", "set", "kind")}), verdict(row["before"], c["kind"]), "->",
              verdict(row["after"], c["kind"]), row["before"]["named"], row["after"]["named"], flush=True)
        write(rows, args.tag, cmd)
    M.RAD_SHARE_STARTS = VARIANTS["after"]
    return 0


if __name__ == "__main__":
    sys.exit(main())
