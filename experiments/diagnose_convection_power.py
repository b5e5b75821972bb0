"""Is natural convection detectable at all? The diagnosis' own tests on the true form.

Convection cases of the development sets (`diagnose_heldout_hard.py` kind `convection_hT`, loss
$a\\Delta + c\\Delta|\\Delta|^{1/3}$) that the diagnosis names nothing: is that the candidate's
form (or its fit), or the record's power? For each case this script

1. runs `jthermo.diagnose` and reads its own statistics of `radiative_loss` (the likelihood ratio
   on the estimation record, the validation Diebold-Mariano $z$, their critical values at the
   Bonferroni level `ALPHA / K`, `not_worse`) and the baseline residuals it tested against;
2. fits, per zone and independently of the library's fitting code
   (`diagnose_convection_oracle.fit_zone`: SciPy trust-region least squares, five starts of the
   share), the *generator's own* form (`conv`, the oracle) and the library's T⁴ form (`rad`);
3. applies the diagnosis' tests (`decide.likelihood_ratio`, `decide.predictive_z`,
   `decide.thresholds(K, N)`: one added parameter per zone, nothing re-estimated on validation
   beyond the initial state and, unmeasured, the surroundings level, as for `radiative_loss`)
   to the oracle's residuals, against the library's baseline residuals and against the oracle's
   own baseline fit.

If the true form passes both tests and T⁴ does not, the candidate's form or fit is the cause;
if neither passes, the record is power-limited and naming nothing is right.
Seed sets 15-19 are reserved for final scoring and refused.

    .venv/bin/python experiments/diagnose_convection_power.py 2:14 17:14 --max-zones 9

Writes `experiments/results/diagnose_convection_power.{md,json}` (after every case).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from jthermo.data import atomic_write_text
from jthermo.diagnose import decide as D
from jthermo.diagnose import diagnose

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_convection_oracle as O
import diagnose_heldout_hard as H

ROOT = Path(__file__).resolve().parents[1]
RESERVED = range(15, 20)


def oracle_residuals(c, est, val):
    """Per-zone fits of base / rad / conv: estimation residuals (simulation error) and
    validation residuals, each `(T, n)`, and the fitted shares."""
    ts = float(est.ts)
    ye, ue, yv, uv = (np.asarray(a, float) for a in (est.y, est.u, val.y, val.u))
    n = ye.shape[1]
    free = 0.0 if c["measured_ambient"] else 1.0
    level = float(est.w[:, 0].mean()) if not free else float(ye[0].min() - 1.0)
    t_ref = float(ye.mean())
    forms = ("base", "rad", "conv")
    Re, Ev, share = ({f: [] for f in forms} for _ in range(3))
    for z in range(n):
        d_ref = float(ye[:, z].mean() - level)
        th = np.zeros(3 + ue.shape[1] + 1)
        th[0] = np.log(1.0 / 400.0)
        th[1:1 + ue.shape[1]] = np.log(max(d_ref, 1.0) / 400.0 / max(ue.mean(), 0.05) / ue.shape[1])
        th[1 + ue.shape[1]] = ye[0, z]
        thb, _ = O.fit_zone("base", ue, ye[:, z], ts, level, free, t_ref, d_ref, th)
        for f in forms:
            thf = thb if f == "base" else O.fit_zone(f, ue, ye[:, z], ts, level, free, t_ref, d_ref, thb)[0]
            res, _ = O.fitter(f, ue, ye[:, z], ts, level, free, t_ref, d_ref)
            Re[f].append(np.asarray(res(thf)))
            Ev[f].append(O.validate_zone(thf, f, uv, yv[:, z], ts, level, free, t_ref, d_ref))
            x = thf[3 + ue.shape[1]]
            share[f].append(round(float(O.RHO_MAX / (1 + np.exp(-x))), 3) if f != "base" else None)
    st = lambda d: {f: np.stack(d[f], axis=1) for f in forms}
    return st(Re), st(Ev), share


def tests(R0, E0, R1, E1, yv, K, n):
    """The diagnosis' two tests of a one-parameter-per-zone candidate (as `select.diagnose`)."""
    zc, lc = D.thresholds(K, n)
    lr = D.likelihood_ratio(R0, R1)
    z = D.predictive_z(E0, E1, 0.0)
    nw = D.not_worse(yv, E1, E0)
    return {"lr": round(lr, 2), "lr_crit": round(lc, 2), "z": round(z, 2), "z_crit": round(zc, 2),
            "not_worse": nw, "val_reduction": round(1.0 - float(np.mean(E1 ** 2) / np.mean(E0 ** 2)), 4),
            "passes": bool(lr >= lc and z >= zc and nw)}


def run_case(i, s, max_zones):
    c = H.draw_case(i, None, max_zones, s)
    est, val = H.make_record(c)
    yv = np.asarray(val.y, float)
    n = yv.shape[1]
    res = diagnose(est, val)
    A = res["_arrays"]
    K = res["decision"]["candidates_tested"]
    cand = next(r for r in res["candidates"] if r["mechanism"] == "radiative_loss")
    R0, E0 = A["resid_est"], A["resid_val"]["baseline"]
    lib = tests(R0, E0, A["resid_est_candidates"]["radiative_loss"], A["resid_val"]["radiative_loss"], yv, K, n)
    lib["library_reported"] = {"lr": round(cand["estimation_lr"], 2), "z": round(cand["validation_z"], 2),
                               "significant": cand["significant"]}
    Ro, Eo, share = oracle_residuals(c, est, val)
    out = {"case": i, "set": s, "kind": c["kind"], "zones": n, "ts": round(c["ts"], 2),
           "noise_C": round(c["noise"], 3), "measured_ambient": c["measured_ambient"],
           "truth": H.describe(c), "K": K,
           "named": [f["mechanism"] for f in res["findings"]],
           "top_confidence": res["findings"][0]["confidence"] if res["findings"] else None,
           "top_rivals": res["findings"][0]["rivals"] if res["findings"] else [],
           "candidates": [{k: r[k] for k in ("mechanism", "validation_z", "estimation_lr", "significant",
                                             "val_reduction")} for r in res["candidates"]],
           "baseline_fit": round(res["baseline"]["mean_fit_percent"], 2),
           "library_rad": lib,
           "base_sse_library_vs_oracle": [round(float(np.sum(R0 ** 2)), 3), round(float(np.sum(Ro["base"] ** 2)), 3)],
           "oracle_vs_library_base": {f: tests(R0, E0, Ro[f], Eo[f], yv, K, n) for f in ("rad", "conv")},
           "oracle_vs_oracle_base": {f: tests(Ro["base"], Eo["base"], Ro[f], Eo[f], yv, K, n)
                                     for f in ("rad", "conv")},
           "share": share,
           "z_conv_over_rad_oracle": round(D.predictive_z(Eo["rad"], Eo["conv"]), 2),
           "z_conv_oracle_over_rad_library": round(D.predictive_z(A["resid_val"]["radiative_loss"], Eo["conv"]), 2)}
    jax.clear_caches()
    return out


def cell(t):
    return (f"{t['lr']:.1f}/{t['lr_crit']:.1f}, {t['z']:.2f}/{t['z_crit']:.2f}, "
            f"{100 * t['val_reduction']:.1f} % {'**pass**' if t['passes'] else 'fail'}")


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+", help="case:set pairs, e.g. 2:14")
    ap.add_argument("--max-zones", type=int, default=9)
    args = ap.parse_args(argv)
    plan = [tuple(int(v) for v in s.split(":")) for s in args.cases]
    if any(s in RESERVED for _, s in plan):
        raise SystemExit("seed sets 15-19 are reserved for final scoring")
    cmd = "python experiments/diagnose_convection_power.py " + " ".join(argv if argv is not None else sys.argv[1:])
    rows = []
    lines = ["# Convection: the diagnosis' tests on the true form and on T⁴ ()", "",
             f"Made by `{cmd}`. Each cell: estimation likelihood ratio / its critical value, validation "
             "z / its critical value (Bonferroni level ALPHA / K, one parameter per zone), validation MSE "
             "reduction, and whether both tests and `not_worse` pass. `library rad`: the diagnosis' own "
             "radiative_loss candidate; `oracle rad` / `oracle conv`: independent per-zone SciPy fits of "
             "T⁴ and of the generator's own form c·Δ|Δ|^{1/3}, tested against the library's baseline "
             "residuals (and, last columns, against the oracle's own baseline fit).", "",
             "| case:set | N | Ts s | noise °C | share | named | library rad | oracle rad | oracle conv | "
             "oracle conv vs own base | z conv>rad (oracle) | conv share found | base SSE lib / oracle | CPU s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for i, s in plan:
        c0 = os.times()
        r = run_case(i, s, args.max_zones)
        r["cpu_s"] = round(sum(os.times()[:2]) - sum(c0[:2]), 1)
        rows.append(r)
        ob, oo = r["oracle_vs_library_base"], r["oracle_vs_oracle_base"]
        lines.append(f"| {i:02d}:{s} | {r['zones']} | {r['ts']} | {r['noise_C']} | {r['truth'].get('conv_share')} | "
                     f"{', '.join(r['named']) or '-'} | {cell(r['library_rad'])} | {cell(ob['rad'])} | "
                     f"{cell(ob['conv'])} | {cell(oo['conv'])} | {r['z_conv_over_rad_oracle']} | "
                     f"{r['share']['conv']} | {r['base_sse_library_vs_oracle'][0]} / {r['base_sse_library_vs_oracle'][1]} | "
                     f"{r['cpu_s']:.0f} |")
        print(lines[-1], flush=True)
        out = ROOT / "experiments" / "results" / "diagnose_convection_power"
        atomic_write_text(out.with_suffix(".md"), "\n".join(lines + ["", f"1-min load {os.getloadavg()[0]:.1f}"]) + "\n")
        atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
