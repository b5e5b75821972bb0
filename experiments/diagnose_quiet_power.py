"""Can the quiet misses of the held-out study be detected at all? (issue 14, item 3)

For the kinds the held-out study (`diagnose_heldout_hard.py`) has missed by naming nothing
(fractional delay, lamp saturation, unmeasured ambient drift, convection), this gives per
development case and zone (seed sets 1, 2, 4 by default; never a scoring set) the size of what
the mechanism leaves for a diagnosis to find: the rms $r$ of the noise-free estimation output's
residual from the best model of the baseline's class (one zone, first order, free loss rate,
heater gains, surroundings level and initial temperature: `diagnose_convection_form.best_linear_rms`)
against the sensor noise $\\sigma$, and the noncentrality that residual would give the estimation
likelihood-ratio test if a candidate captured all of it and the noise were white,
$\\lambda = T (r^2 - r_0^2) / \\sigma^2$, where $r_0$ is the same measure on the same plant and
inputs without the mechanism (the floor: the generator's Euler steps against the exact hold).
Near the 1-parameter critical value of the test (Bonferroni over the candidates) or below it the
test is quiet whatever the candidate; AR noise lowers the real figure further. NumPy only.

    .venv/bin/python experiments/diagnose_quiet_power.py [--seed-sets 1 2 4]

Writes `experiments/results/diagnose_quiet_power.{md,json}`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.stats import chi2

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H
from diagnose_convection_form import best_linear_rms

from jthermo.data import atomic_write_text
from jthermo.diagnose.decide import ALPHA

ROOT = Path(__file__).resolve().parents[1]
KINDS = ("frac_delay", "lamp_saturation", "ambient_drift", "convection_hT")
#: candidates the study's diagnosis tests on a record (Bonferroni), one added parameter
N_TESTS = 8


def case_rows(i: int, kind: str, seed_set: int, max_zones: int) -> list[dict]:
    c = H.draw_case(i, kind, max_zones, seed_set)
    T = c["n_est"]
    u = H.inputs(c, T + c["n_val"])
    y = H.simulate(c, u)[:T]
    u = u[:T]
    # the same plant without the mechanism: the measure's own floor (Euler steps against the
    # model's exact hold, the record's start)
    c0 = {k: v for k, v in c.items() if k not in ("conv_share", "delay_s", "beta")}
    c0["kind"] = "null"
    y0 = H.simulate(c0, np.concatenate([u, u[:c["n_val"]]]))[:T]
    out = []
    for z in range(c["zones"]):
        r = best_linear_rms(y[:, z], u, c["ts"])
        r0 = best_linear_rms(y0[:, z], u, c["ts"])
        out.append({"seed_set": seed_set, "case": f"{i:02d}_{kind}", "zone": z + 1, "zones": c["zones"],
                    "ts": c["ts"], "samples": T, "physics": H.describe(c), "residual_rms_C": r,
                    "floor_rms_C": r0, "noise_C": c["noise"],
                    "lambda": T * max(r ** 2 - r0 ** 2, 0.0) / c["noise"] ** 2})
    return out


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed-sets", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--max-zones", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    ap.add_argument("--sample-at-end", action="store_true",
                    help="records as the study made them before 2026-11-25 (y_k read after u_k acted)")
    ap.add_argument("--tag", default="")
    args = ap.parse_args(argv)
    H.SAMPLE_AT_END = args.sample_at_end
    if 3 in args.seed_sets or 5 in args.seed_sets:
        raise SystemExit("seed sets 3 and 5 are scoring sets: not looked at here")
    rows = [r for ss in args.seed_sets for i, k in enumerate(H.KINDS) if k in KINDS
            for r in case_rows(i, k, ss, args.max_zones)]
    floor = [r for ss in args.seed_sets for r in case_rows(0, "null", ss, args.max_zones)]
    crit = float(chi2.isf(ALPHA / N_TESTS, 1))
    out = Path(args.out)
    tag = f"_{args.tag}" if args.tag else ""
    atomic_write_text(out / f"diagnose_quiet_power{tag}.json",
                      json.dumps({"rows": rows, "null_floor": floor, "lr_critical_1dof": crit}, indent=1))
    lines = ["# Quiet misses: is the effect detectable at all? (issue 14)", "",
             (f"Made by `python experiments/diagnose_quiet_power.py --seed-sets {' '.join(map(str, args.seed_sets))}"
              f"{' --sample-at-end' if args.sample_at_end else ''}{' --tag ' + args.tag if args.tag else ''}` "
              "(development seed sets of `diagnose_heldout_hard.py`; NumPy only)."),
             ("Sensor read at the **end** of each sample (y_k = x(t_{k+1}), as the study's records were made "
              "before 2026-11-25: one sample ahead of the models)." if args.sample_at_end else
              "Sensor read at the start of each sample (y_k = x(t_k), as the models)."),
             "Residual: rms of the noise-free estimation output's residual from the best first-order linear",
             "zone model (the baseline's class, °C); floor: the same without the mechanism; λ = T (r² - r0²) / σ²,",
             "the estimation LR's noncentrality if a candidate captured all of the excess (white noise); the",
             f"1-parameter critical value is {crit:.1f}.", "",
             "| seed set | case | zone | Ts s | physics | residual °C | floor °C | noise °C | λ |",
             "|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['seed_set']} | {r['case']} | {r['zone']}/{r['zones']} | {r['ts']:.2f} | {json.dumps(r['physics'])} | "
              f"{r['residual_rms_C']:.3f} | {r['floor_rms_C']:.3f} | {r['noise_C']:.3f} | {r['lambda']:.0f} |" for r in rows]
    lines += ["", "The generator's null records (zones of case 00): residual "
              + ", ".join(f"{r['residual_rms_C']:.3f}" for r in floor) + " °C."]
    for k in KINDS:
        lam = [r["lambda"] for r in rows if r["case"].endswith(k)]
        lines.append(f"- {k}: zones with λ below the critical value {sum(v < crit for v in lam)}/{len(lam)}; "
                     f"median λ {np.median(lam):.0f}.")
    atomic_write_text(out / f"diagnose_quiet_power{tag}.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
