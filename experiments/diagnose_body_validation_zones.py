"""Why a slow body's per-zone fit is not significant on some records: per zone, the
validation RMS error of the baseline, the `heat_accumulation` and the `ambient_variation`
candidates (each simulated coupled, record states re-estimated, as the diagnosis's test), their
estimation RMS, and the body's fitted wall (τ_w, γ), loss time constant, share c/(a + c), wall
state and surroundings level offset.

    .venv/bin/python experiments/diagnose_body_validation_zones.py 13:17 [4:18 ...]

Each argument is CASE:SEED_SET of `diagnose_heldout_hard.py` at up to 9 zones (scored sets
only). Writes `experiments/results/diagnose_body_validation_zones.md`.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose
from jthermo.diagnose import mechanisms as M

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_body_drift_cases as C
import diagnose_heldout_hard as H


def one(spec: str) -> list[str]:
    i, s = map(int, spec.split(":"))
    if s in C.UNSCORED_SETS or s >= C.FIRST_UNSCORED:
        raise SystemExit(f"seed set {s} has not been scored yet: reserved for held-out scoring")
    c = H.draw_case(i, None, 9, s)
    est, val = H.make_record(c)
    res = diagnose(est, val)
    A, mo = res["_arrays"], res["_models"]
    lay = mo["layout"]
    rms = lambda e: np.sqrt(np.mean(np.asarray(e) ** 2, axis=0))
    th = np.asarray(mo["theta"]["heat_accumulation"])
    tauw, gam = M.wall_parameters(th[:, lay.sl("log_tauw")][:, 0], th[:, lay.sl("log_gamma")][:, 0])
    a, cw = np.exp(th[:, lay.sl("log_a")][:, 0]), np.exp(th[:, lay.sl("log_c")][:, 0])
    top = res["findings"][0]["mechanism"] if res["findings"] else None
    out = [f"## case {i:02d}, set {s}: {c['kind']}, N = {c['zones']}, physics {H.describe(c)}, named {top}", "",
           "| zone | val RMS baseline °C | val RMS body | val RMS drift | est RMS body | est RMS drift "
           "| τ_w s | γ | 1/a s | share c/(a+c) | wall state °C | level offset °C |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rv, re = A["resid_val"], A["resid_est_candidates"]
    cols = [rms(rv["baseline"]), rms(rv["heat_accumulation"]), rms(rv["ambient_variation"]),
            rms(re["heat_accumulation"]), rms(re["ambient_variation"])]
    for z in range(c["zones"]):
        out.append(f"| {z + 1} | " + " | ".join(f"{v[z]:.3f}" for v in cols)
                   + f" | {tauw[z]:.0f} | {gam[z]:.2f} | {1 / a[z]:.0f} | {cw[z] / (a[z] + cw[z]):.3f} | "
                   f"{th[z, lay.sl('xw0')][0]:.1f} | {th[z, lay.sl('ts0')][0]:.1f} |")
    return out + [""]


def main(argv=None) -> int:
    specs = (argv if argv is not None else sys.argv[1:]) or ["13:17"]
    t0 = time.perf_counter()
    lines = ["# A slow body's per-zone fits on validation", "",
             f"Made by `python experiments/diagnose_body_validation_zones.py {' '.join(specs)}`.", ""]
    for spec in specs:
        lines += one(spec)
        print("\n".join(lines[-6:]), flush=True)
    lines.append(f"Wall {time.perf_counter() - t0:.0f} s.")
    atomic_write_text(Path("experiments/results/diagnose_body_validation_zones.md"), "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
