"""Does `converged` mean converged? ARMAX / OE / BJ at the default path's orders on W1 with N
zones (6000 samples, the default path's solver settings, `fit_polynomial` defaults): per output
row, the LM steps taken and the relative cost decrease the Gauss–Newton step from the result
would still give (converged below 1e-4, MATLAB pem's rule).

Rows stopped at the step cap (200) while still improving get further rounds
(`fit_polynomial(extend_rounds=4)`, `pem_numpy.extend_rows`). For each family and engine the
fit is run with `extend_rounds=0` (the cap final, as before) and with the default, in the same
process: which rows stopped at the cap, how many steps the continued rows took, the CPU seconds
of the continuation alone (timed around `extend_rows`), the remaining gain, and what the row
looked like (its largest |F pole| over the inputs and that input's gain).

Usage: python experiments/polynomial_converged.py --n 16 [--seed 0] [--engines jax numpy]
Writes experiments/results/polynomial_converged.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: the default path's automatic orders at N = 16 (W1 seed 0)
ORDERS = {"oe": {"nb": 1, "nf": 1}, "bj": {"nb": 1, "nc": 1, "nd": 2, "nf": 1},
          "armax": {"na": 1, "nb": 1, "nc": 2}}


def run(d, fam: str, engine: str) -> dict:
    """Both fits of one family/engine; the continuation's CPU s from a timer around it."""
    import jthermo.identify.polynomial as P

    spent = []
    own = P.extend_rows

    def timed(*a, **k):
        t0 = time.process_time()
        out = own(*a, **k)
        spent.append(time.process_time() - t0)
        return out

    P.extend_rows = timed
    try:
        m0, cut = P.fit_polynomial(d.y, d.u, ts=d.ts, engine=engine, extend_rounds=0, **ORDERS[fam])
        m1, cont = P.fit_polynomial(d.y, d.u, ts=d.ts, engine=engine, **ORDERS[fam])
    finally:
        P.extend_rows = own
    return {"cut": (m0, cut), "cont": (m1, cont), "cpu": sum(spent)}


def pole_note(model, row: int) -> str:
    """The input whose F pole is largest in modulus on `row`, with its gain b and DC gain."""
    f = np.asarray(model.f)[row]                     # (nu, nf)
    if f.size == 0:
        return "—"
    j = int(np.argmax(np.abs(f[:, 0])))
    b = float(np.asarray(model.b)[row, j].sum())
    return f"input {j + 1}: pole {-f[j, 0]:.7f}, b {b:.2e}, DC gain {b / (1 + f[j].sum()):.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--families", nargs="+", default=["oe", "bj"], choices=list(ORDERS))
    ap.add_argument("--engines", nargs="+", default=["jax", "numpy"], choices=("jax", "numpy"))
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import jax

    jax.config.update("jax_enable_x64", True)
    from identification import load_workloads

    from jthermo.data import from_arrays
    from jthermo.validate import compare

    W = load_workloads()
    est, val = W.make_dataset(args.n, 6000, args.seed, 1), W.make_dataset(args.n, 3000, args.seed, 2)
    d, v = from_arrays(est["u"], 25.0 + est["y"]), from_arrays(val["u"], 25.0 + val["y"])
    out = ROOT / "experiments" / "results" / "polynomial_converged.md"
    command = "python experiments/polynomial_converged.py " + " ".join(argv or sys.argv[1:])
    lines = [f"# `converged` per output row, W1 N = {args.n}, seed {args.seed}", "",
             f"`{command}`; load (1-minute) {os.getloadavg()[0]:.1f} at the start. Cap = "
             "`max_steps` 200 per row; 'cap final' = `extend_rounds=0` (before), 'continued' = "
             "the default `extend_rounds=4`. Validation fit: `compare` on 3000 validation "
             "samples (initial state estimated), mean over outputs.", "",
             "| family | engine | rows at the cap | not converged, cap final (gain) | continued: "
             "steps | continued: converged (largest gain) | continuation CPU s | val fit %, "
             "cap final → continued | the continued row |", "|---|---|---|---|---|---|---|---|---|"]
    for fam in args.families:
        for engine in args.engines:
            r = run(d, fam, engine)
            (m0, cut), (m1, cont) = r["cut"], r["cont"]
            st0, st1 = np.asarray(cut["n_steps"]), np.asarray(cont["n_steps"])
            imp0, imp1 = np.asarray(cut["expected_improvement"]), np.asarray(cont["expected_improvement"])
            capped = np.flatnonzero(st0 >= 200)
            bad = np.flatnonzero(~np.asarray(cut["row_converged"]))
            grown = np.flatnonzero(st1 > st0)
            f0, f1 = compare(m0, v)["mean_fit_percent"], compare(m1, v)["mean_fit_percent"]
            lines.append(
                f"| {fam} | {engine} | {', '.join(str(i + 1) for i in capped) or '—'} | "
                f"{', '.join(f'{i + 1} ({imp0[i]:.2e})' for i in bad) or '—'} | "
                f"{', '.join(f'{i + 1}: {st0[i]} → {st1[i]}' for i in grown) or '—'} | "
                f"{int(np.sum(cont['row_converged']))}/{st1.size} ({imp1.max():.2e}) | "
                f"{r['cpu']:.2f} | {f0:.4f} → {f1:.4f} | "
                f"{'; '.join(f'row {i + 1} {pole_note(m1, i)}' for i in grown) or '—'} |")
            out.write_text("\n".join(lines) + "\n")
            print(lines[-1], flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
