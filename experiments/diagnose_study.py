"""Blind diagnosis study on the virtual printer.

Each case builds a printer with one concealed mechanism (or two, or none), records one hour of
estimation data and half an hour of validation data at Ts = 1 s (PRBS on every heater), runs
`jthermo.diagnose.diagnose` without telling it anything, and tabulates top-1 accuracy per
mechanism, false findings on the null cases, recovered parameters against the truth, the fit
gain and the time per case. It also runs the diagnosis on the real TCLab recordings.

    .venv/bin/python experiments/diagnose_study.py [--quick] [--cases N] [--out experiments/results]

Case k of `CASES` is seeded `--seed + k` whatever `--only` / `--cases` select, so a single
case rerun alone gets the record of the whole study (before 2026-11-25 `--only` reseeded by the
position in the selection: experiments/results/diagnose_study_bisect.md).

Writes `experiments/results/diagnose_study.md` (and `.json`), updated after every case.
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

from jthermo import printer as P
from jthermo.data import atomic_write_text, load, split
from jthermo.diagnose import diagnose, to_json

ROOT = Path(__file__).resolve().parents[1]

# (name, zones, effects, noise_std, truth parameters to compare)
CASES = [
    ("conduction", 4, {"lateral_conduction": {}}, 0.05, {}),
    ("lag_10s", 6, {"heater_lag": {"time_constant_s": 10.0}}, 0.05, {"time_constant_s": 10.0}),
    ("delay_3s", 4, {"input_delay": {"delay_s": 3}}, 0.05, {"delay_s": 3.0}),
    ("recoat_60s", 5, {"recoat_cooling": {}}, 0.05, {"period_s": 60.0, "drop_C": 3.0}),
    ("null_coloured", 4, {"sensor_noise": {}}, 0.05, {}),
    ("nonlinearity_1.5", 4, {"input_nonlinearity": {"exponent": 1.5}}, 0.05, {"exponent": 1.5}),
    ("accumulation", 6, {"heat_accumulation": {}}, 0.05, {"time_constant_s": 1500.0}),
    ("ambient", 4, {"ambient_variation": {}}, 0.05, {}),
    ("radiation_strong", 4, {"radiative_loss": {"area_m2": 0.03}}, 0.05, {}),
    ("null_white", 9, {}, 0.1, {}),
    ("conduction_weak", 9, {"lateral_conduction": {"conductance_W_K": 0.06}}, 0.05, {}),
    ("delay_2s", 9, {"input_delay": {"delay_s": 2}}, 0.05, {"delay_s": 2.0}),
    ("lag_4s", 4, {"heater_lag": {"time_constant_s": 4.0}}, 0.1, {"time_constant_s": 4.0}),
    ("recoat_90s_1C", 6, {"recoat_cooling": {"period_s": 90.0, "drop_C": 1.0}}, 0.05,
     {"period_s": 90.0, "drop_C": 1.0}),
    ("nonlinearity_0.7", 6, {"input_nonlinearity": {"exponent": 0.7}}, 0.05, {"exponent": 0.7}),
    ("null_coloured_9", 9, {"sensor_noise": {"coloured_std_C": 0.15}}, 0.05, {}),
    ("radiation", 5, {"radiative_loss": {}}, 0.05, {}),
    ("lag+recoat", 4, {"heater_lag": {}, "recoat_cooling": {}}, 0.05, {}),
    ("radiation_noisy_7", 7, {"radiative_loss": {"area_m2": 0.02}}, 0.1, {}),
    ("accumulation_8_fast", 8, {"heat_accumulation": {"share": 0.3, "time_constant_s": 800.0}}, 0.1,
     {"time_constant_s": 800.0}),
    ("null_white_6", 6, {}, 0.05, {}),
]
MECH_OF = {"conduction": "lateral_conduction", "lag": "heater_lag", "delay": "input_delay",
           "recoat": "recoat_cooling", "nonlinearity": "input_nonlinearity",
           "accumulation": "heat_accumulation", "ambient": "ambient_variation",
           "radiation": "radiative_loss"}
CONCEALABLE = set(MECH_OF.values())


def run_case(name, zones, effects, noise, seed):
    pr = P.make_printer(zones, effects=effects, seed=seed)
    data = P.generate(pr, "prbs", duration=5400.0, seed=seed, noise_std=noise)
    est, val = split(data, 2 / 3)
    jax.clear_caches()              # every case pays its own compilation, as a fresh CLI call would
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    res = to_json(diagnose(est, val, seed=seed))
    res["cpu_seconds"] = time.process_time() - c0
    res["load"] = max(load0, os.getloadavg()[0])
    return res, time.perf_counter() - t0


def real_cases():
    out = []
    base = ROOT.parent / "shared" / "data" / "real"
    if not base.exists():
        base = ROOT / ".." / "shared" / "data" / "real"
    pairs = [("tclab_cace2020 id_2heaters → val_2heaters", "tclab_cace2020/id_2heaters/data.csv",
              "tclab_cace2020/val_2heaters/data.csv"),
             ("tclab_rawlings prbs_kr2022 (2/3 | 1/3)", "tclab_rawlings/prbs_kr2022/data.csv", None)]
    for label, a, b in pairs:
        pa = base / a
        if not pa.exists():
            continue
        d = load(pa)
        if b is None:
            est, val = split(d, 2 / 3)
        else:
            est, val = d, load(base / b)
        t0 = time.perf_counter()
        res = to_json(diagnose(est, val))
        out.append((label, res, time.perf_counter() - t0))
    return out


def fmt_params(p):
    keep = {k: v for k, v in p.items() if isinstance(v, (int, float))}
    return ", ".join(f"{k}={v:.3g}" for k, v in keep.items())


def write(rows, real, path):
    lines = ["# Diagnosis study: concealed physics on the virtual printer", "",
             "Generated by `experiments/diagnose_study.py` (one hour estimation + 30 min validation,",
             "Ts = 1 s, PRBS on every heater, `jthermo.printer`). The diagnosis runs blind.",
             "Fits are simulation fits on the validation record.", "",
             "| case | zones | noise (°C) | concealed | verdict | top finding | correct | baseline fit % | augmented fit % | gain (points) | parameters found | truth | wall (s) | CPU (s) | load |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['zones']} | {r.get('noise', float('nan')):g} | {', '.join(r['concealed']) or 'none'} | {r['verdict']} | "
                     f"{r['top'] or '—'} | {'yes' if r['correct'] else 'NO'} | {r['base_fit']:.1f} | "
                     f"{r['aug_fit']:.1f} | {r['gain']:.2f} | {r['params']} | {r['truth']} | {r['seconds']:.0f} | "
                     f"{r.get('cpu_seconds', float('nan')):.0f} | {r.get('load', float('nan')):.1f} |")
    conc = [r for r in rows if r["concealed"]]
    nulls = [r for r in rows if not r["concealed"]]
    acc = sum(r["correct"] for r in conc)
    lines += ["", "## Summary", "",
              f"- top-1 correct: {acc} of {len(conc)} cases with a concealed mechanism",
              (f"- null cases answered `no_significant_mismatch`: "
              f"{sum(r['verdict'] == 'no_significant_mismatch' for r in nulls)} of {len(nulls)}"),
              (f"- median fit gain (cases with a concealed mechanism): "
              f"{np.median([r['gain'] for r in conc]) if conc else float('nan'):.2f} points"),
              (f"- time per case: median {np.median([r['seconds'] for r in rows]) if rows else 0:.0f} s, "
              f"max {max([r['seconds'] for r in rows], default=0):.0f} s wall on this machine's 2 cores shared "
              f"with other jobs (1-min load average {min([r.get('load', np.nan) for r in rows], default=0):.1f}-"
              f"{max([r.get('load', np.nan) for r in rows], default=0):.1f}); CPU time median "
              f"{np.median([r.get('cpu_seconds', np.nan) for r in rows]) if rows else 0:.0f} s, max "
              f"{max([r.get('cpu_seconds', 0) for r in rows], default=0):.0f} s (compilation included)"), ""]
    per = {}
    for r in conc:
        for m in r["concealed"]:
            per.setdefault(m, []).append(r["correct"])
    if per:
        lines += ["| mechanism | correct / cases |", "| --- | --- |"]
        lines += [f"| {m} | {sum(v)} / {len(v)} |" for m, v in sorted(per.items())]
    if real:
        lines += ["", "## Real recordings (TCLab)", "",
                  "| data | verdict | findings | baseline fit % | augmented fit % | parameters | time (s) |",
                  "| --- | --- | --- | --- | --- | --- | --- |"]
        for label, res, sec in real:
            f = ", ".join(x["mechanism"] for x in res["findings"]) or "—"
            pp = "; ".join(f"{m}: {fmt_params(v)}" for m, v in res["augmented"]["parameters"].items())
            lines.append(f"| {label.replace('|', '/')} | {res['verdict']} | {f} | {res['baseline']['mean_fit_percent']:.1f} | "
                         f"{res['augmented']['mean_fit_percent']:.1f} | {pp} | {sec:.0f} |")
    atomic_write_text(path, "\n".join(lines) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the first 8 cases only")
    ap.add_argument("--cases", type=int, default=None, help="run the first N cases")
    ap.add_argument("--only", default=None, help="comma-separated case names")
    ap.add_argument("--no-real", action="store_true")
    ap.add_argument("--real-only", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--merge", default=None,
                    help="comma-separated JSON results (of runs with other --only/--out) merged into the report")
    ap.add_argument("--one-thread", action="store_true",
                    help="JAX's CPU backend with one intra-op thread (runtime.one_thread_backend), as "
                         "`jthermo simulate` makes it on a busy machine (`jthermo diagnose` does not: "
                         "its fitted values would then depend on the load)")
    a = ap.parse_args(argv)
    cases = CASES[:8] if a.quick else CASES
    if a.one_thread:
        from jthermo import runtime

        if not runtime.one_thread_backend():
            raise SystemExit("--one-thread: the CPU backend exists already or cannot be made with one thread")
    if a.cases:
        cases = CASES[: a.cases]
    if a.only:
        names = set(a.only.split(","))
        cases = [c for c in CASES if c[0] in names]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.merge is not None:
        rows, real = [], []
        for path in a.merge.split(","):
            d = json.loads(Path(path).read_text())
            rows = [r for r in rows if r["case"] not in {c["case"] for c in d["cases"]}]
            rows += d["cases"]          # a later file's run of the same case replaces it
            real += [(l, r, r.get("seconds", float("nan"))) for l, r in d.get("real", {}).items()]
        write(rows, real, out / "diagnose_study.md")
        return 0
    rows, real, raw = [], [], {}
    if a.real_only:
        cases = []
    for name, zones, effects, noise, truth in cases:
        # each case's record is seeded by its place in CASES, whatever --only / --cases select
        seed = a.seed + next(k for k, c in enumerate(CASES) if c[0] == name)
        res, sec = run_case(name, zones, effects, noise, seed)
        concealed = sorted(e for e in effects if e in CONCEALABLE)
        top = res["findings"][0]["mechanism"] if res["findings"] else None
        found = [f["mechanism"] for f in res["findings"]]
        correct = (res["verdict"] == "no_significant_mismatch") if not concealed else (top in concealed)
        gain = res["augmented"]["mean_fit_percent"] - res["baseline"]["mean_fit_percent"]
        rows.append({"case": name, "zones": zones, "concealed": concealed, "verdict": res["verdict"], "top": top,
                         "found": found, "correct": bool(correct), "base_fit": res["baseline"]["mean_fit_percent"],
                         "aug_fit": res["augmented"]["mean_fit_percent"], "gain": gain,
                         "params": fmt_params(res["findings"][0]["parameters"]) if res["findings"] else "",
                         "truth": ", ".join(f"{k}={v:g}" for k, v in truth.items()), "seconds": sec,
                         "cpu_seconds": res["cpu_seconds"], "load": res["load"], "noise": noise,
                         "seed": seed})
        raw[name] = res
        print(f"{name}: {res['verdict']} top={top} found={found} gain={gain:.2f} {sec:.0f}s", flush=True)
        write(rows, real, out / "diagnose_study.md")
        atomic_write_text(out / "diagnose_study.json", json.dumps({"cases": rows}, indent=1, default=str))
    if not a.no_real:
        real = real_cases()
        for label, res, sec in real:
            print(f"{label}: {res['verdict']} {[f['mechanism'] for f in res['findings']]} "
                  f"{res['baseline']['mean_fit_percent']:.1f} -> {res['augmented']['mean_fit_percent']:.1f}",
                  flush=True)
        write(rows, real, out / "diagnose_study.md")
        atomic_write_text(out / "diagnose_study.json",
                          json.dumps({"cases": rows, "real": {l: r for l, r, _ in real}}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
