"""Checks on the records of `benchmarks/identification_scale.py` (seed 0).

`ss`: is the state-space gap at N = 16 (default: simulation focus; operating point "mean" as in
`ss_focus_scale.py`) optimisation or variance? Full A (`coupling="full"`, the earlier default)
and the true structure, diagonal A (`coupling="diagonal"`), at the true order. Simulation error (sum of squares, initial state
by least squares) of the fit and of the true model on the estimation and the validation record,
and the static gains' largest relative error. A fit whose estimation error is *below* the true
model's while its validation error is above it has fitted the noise (the variance of its free
parameters); it has not stopped early.

`greybox`: why does the bed report `converged: false` at N = 16, and do more steps help?
`fit_greybox` at several step caps: seconds, `converged`, zones not converged, the largest
expected relative gain of a Gauss–Newton step, the smallest heater gain relative to its zone's
largest (log-parametrised, so it can only approach 0) and the validation fit.

Writes `experiments/results/scale_fit_checks.md`.

Usage: python experiments/scale_fit_checks.py ss|greybox [--n 16] [--steps 100 400]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def _dcgain(ss) -> np.ndarray:
    A, B, C = (np.asarray(m) for m in (ss.A, ss.B, ss.C))
    return C @ np.linalg.solve(np.eye(A.shape[0]) - A, B)


def ss_rows(N: int, est, val, truth_model, steps) -> list[str]:
    from jthermo.identify.statespace import fit_statespace, simulation_error
    from jthermo.validate import compare

    del steps
    rows = []
    for coupling in ("full", "diagonal"):
        t, c = time.perf_counter(), time.process_time()
        r = fit_statespace(est, N, operating_point="mean", coupling=coupling)
        sec, cpu = time.perf_counter() - t, time.process_time() - c
        G, Gt = _dcgain(r.model), _dcgain(truth_model)
        m = r.extra["parametrised"]
        free = m.n_params() - (m.A.shape[0] ** 2 - m.A.shape[0] if coupling == "diagonal" else 0)
        rows.append(f"| {N} | {coupling} | {free} | {sec:.1f} | {cpu:.1f} | {r.converged} | "
                    f"{simulation_error(r.model, est):.0f} / "
                    f"{simulation_error(truth_model, est):.0f} | "
                    f"{simulation_error(r.model, val):.0f} / "
                    f"{simulation_error(truth_model, val):.0f} | "
                    f"{np.max(np.abs(G - Gt)) / np.max(np.abs(Gt)):.3f} | "
                    f"{compare(r.model, val)['mean_fit_percent']:.2f} | "
                    f"{compare(truth_model, val)['mean_fit_percent']:.2f} |")
        print(rows[-1], flush=True)
    return rows


def greybox_rows(N: int, est, val, truth_model, steps) -> list[str]:
    from jthermo.identify.greybox import fit_greybox
    from jthermo.validate import compare

    truth = compare(truth_model, val)["mean_fit_percent"]
    rows = []
    for cap in steps:
        t = time.perf_counter()
        r = fit_greybox(est, max_steps=cap)
        sec = time.perf_counter() - t
        g = np.exp(np.asarray(r.model.log_gain))
        rel = float(np.min(g / g.max(axis=1, keepdims=True)))
        rows.append(f"| {N} | {cap} | {sec:.1f} | {r.converged} | "
                    f"{len(r.extra['zones_not_converged'])} | "
                    f"{max(r.extra['expected_improvement']):.2e} | {rel:.1e} | "
                    f"{compare(r.model, val)['mean_fit_percent']:.2f} | {truth:.2f} |")
        print(rows[-1], flush=True)
    return rows


HEADERS = {
    "ss": [("| N | A | free parameters | wall s | CPU s | converged | est. sim. error fit / true | "
           "val. sim. error fit / true | static gain max rel. error | val fit % | true fit % |"),
           "|---|---|---|---|---|---|---|---|---|---|---|"],
    "greybox": [("| N | max_steps | seconds | converged | zones not converged | max expected gain "
                "| min relative heater gain | val fit % | true fit % |"),
                "|---|---|---|---|---|---|---|---|---|"],
}


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    import identification_scale as S

    from jthermo.models.greybox import BedModel

    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=sorted(HEADERS))
    ap.add_argument("--n", type=int, nargs="+", default=[16])
    ap.add_argument("--steps", type=int, nargs="+", default=[100, 400], help="greybox step caps")
    args = ap.parse_args(argv)
    rows_of = {"ss": ss_rows, "greybox": greybox_rows}[args.what]
    lines = [f"# {args.what} at scale (`python experiments/scale_fit_checks.py {args.what} --n "
             + " ".join(map(str, args.n)) + (" --steps " + " ".join(map(str, args.steps))
                                              if args.what == "greybox" else "") + "`)", ""]
    lines += HEADERS[args.what]
    for N in args.n:
        est, _ = S.record(N, S.T_EST, 0, 1)
        val, _ = S.record(N, S.T_VAL, 0, 2)
        capacity, loss, gain = S.bed_plant(N, 0)
        true = BedModel.from_physical(capacity, loss, gain, S.TS).to_statespace()
        lines += rows_of(N, est, val, true, args.steps)
        print(lines[-1], flush=True)
    up = subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    lines += ["", (f"uptime at the end: `{up}` (shared 2-core machine: wall times are inflated "
              "by the load)")]
    out = ROOT / "experiments" / "results" / "scale_fit_checks.md"
    out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
