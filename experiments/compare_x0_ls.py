"""Validation fit of the same fitted model with the two least-squares initial states of
`validate.compare` (issue 12): the generic one (`estimate_initial_state`: normal equations of
the Jacobian of the simulation in x0, all outputs at once, JAX) and the per-output one of
`models.polynomial_numpy.initial_state` (NumPy least squares on the free responses of each
output's own realisation blocks), which `compare` now uses for diagonal-A polynomial models.

The model is fitted once (automatic orders, as `jthermo fit`) on the W1 records of
`benchmarks/identification.py --default-path`; both initial states are then applied to it on the
validation record, and the fit %, the squared-error sum and the x0 condition are reported.

    python experiments/compare_x0_ls.py --n 4 16 --families oe bj
    -> experiments/results/compare_x0_ls.md
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import identification as B  # noqa: E402

from jthermo.data import atomic_write_text, from_arrays  # noqa: E402
from jthermo.identify import fit  # noqa: E402
from jthermo.models import polynomial_numpy  # noqa: E402
from jthermo.validate.simulation import estimate_initial_state  # noqa: E402


def fit_pct(y, yhat):
    return float(np.mean(100 * (1 - np.linalg.norm(y - yhat, axis=0)
                                / np.linalg.norm(y - y.mean(axis=0), axis=0))))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[4, 16])
    ap.add_argument("--families", nargs="+", default=["oe", "bj"])
    ap.add_argument("--out", type=Path, default=ROOT / "experiments/results/compare_x0_ls.md")
    args = ap.parse_args(argv)
    W = B.load_workloads()
    lines = ["# Least-squares initial state of `compare`: generic (JAX) vs per output (NumPy)", "",
             f"`python experiments/compare_x0_ls.py {' '.join(sys.argv[1:] if argv is None else argv)}`: "
             "one fit per row (automatic orders, W1 records in absolute °C, 6000 + 3000 samples), "
             "then its validation simulation fit % from the two initial states.", "",
             "| family | N | orders | states | fit %, generic x0 | fit %, per-output x0 | SSE ratio per-output / generic |",
             "|---|---|---|---|---|---|---|"]
    for N in args.n:
        est, val = W.make_dataset(N, 6000, 0, 1), W.make_dataset(N, 3000, 0, 2)
        e, v = from_arrays(est["u"], 25.0 + est["y"]), from_arrays(val["u"], 25.0 + val["y"])
        for fam in args.families:
            m = fit(e, fam).model
            x_gen = estimate_initial_state(m, v)
            y_gen = np.asarray(m.simulate(v.u, None, x_gen))
            x_np, y_np = polynomial_numpy.initial_state(m, v.y, v.u)
            sse = np.sum((v.y - y_np) ** 2) / np.sum((v.y - y_gen) ** 2)
            o = " ".join(f"{k} {val_}" for k, val_ in m.orders.items() if val_)
            lines.append(f"| {fam} | {N} | {o} | {x_np.size} | {fit_pct(v.y, y_gen):.3f} | "
                         f"{fit_pct(v.y, y_np):.3f} | {sse:.4f} |")
            print(lines[-1], flush=True)
            atomic_write_text(args.out, "\n".join(lines) + "\n")     # after every row
    return 0


if __name__ == "__main__":
    sys.exit(main())
