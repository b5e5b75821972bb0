"""Does `converged` mean converged? ARMAX / OE / BJ at W1's orders and N zones (6000 samples,
seed 0, the default path's solver settings): per output row, the LM steps taken (cap 200) and
the relative cost decrease the Gauss–Newton step from the result would still give (converged
below 1e-4, MATLAB pem's rule).

Usage: python experiments/polynomial_converged.py --n 16
Writes experiments/results/polynomial_converged_n<N>.md.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: W1's true orders and the default path's automatic ones at N = 16
ORDERS = {"oe": {"nb": 1, "nf": 1}, "bj": {"nb": 1, "nc": 1, "nd": 2, "nf": 1},
          "armax": {"na": 1, "nb": 1, "nc": 2}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--families", nargs="+", default=list(ORDERS), choices=list(ORDERS))
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from identification import load_workloads

    from jthermo.data import from_arrays
    from jthermo.identify.polynomial import fit_polynomial

    est = load_workloads().make_dataset(args.n, 6000, 0, 1)
    d = from_arrays(est["u"], 25.0 + est["y"])
    out = ROOT / "experiments" / "results" / f"polynomial_converged_n{args.n}.md"
    lines = [f"# `converged` per output row, N = {args.n}", "",
             f"`python experiments/polynomial_converged.py --n {args.n}`; load (1-minute) "
             f"{os.getloadavg()[0]:.1f} at the start.", "",
             "| family | orders | converged | rows not converged | steps (min/max) | "
             "largest expected improvement | rows at the step cap |", "|---|---|---|---|---|---|---|"]
    for fam in args.families:
        _, info = fit_polynomial(d.y, d.u, ts=d.ts, **ORDERS[fam])
        steps, imp = np.asarray(info["n_steps"]), np.asarray(info["expected_improvement"])
        bad = [int(i) + 1 for i in np.flatnonzero(~np.asarray(info["row_converged"]))]
        o = " ".join(f"{k} {v}" for k, v in ORDERS[fam].items())
        lines.append(f"| {fam} | {o} | {info['converged']} | "
                     f"{', '.join(f'{i} ({imp[i - 1]:.2e})' for i in bad) or '—'} | "
                     f"{steps.min()}/{steps.max()} | {imp.max():.2e} | {int(np.sum(steps >= 200))} |")
        out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
