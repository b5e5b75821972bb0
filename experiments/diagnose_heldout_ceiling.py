"""The validation fit the *true* plant reaches on a development record (its noise-free simulation
against the noisy record): the ceiling no diagnosis can beat (is a miss at a low
baseline fit a failure of the diagnosis or a record whose effect is below the noise?).

    .venv/bin/python experiments/diagnose_heldout_ceiling.py 2:6 10:6 4:6 [--max-zones 3]

Each argument is CASE:SEED_SET of `diagnose_heldout_hard.py`. Writes
`experiments/results/diagnose_heldout_ceiling.md`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from jthermo.data import atomic_write_text

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("cases", nargs="+", help="CASE:SEED_SET")
    ap.add_argument("--max-zones", type=int, default=3)
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    lines = ["# Validation fit of the true plant on development records (noise ceiling)", "",
             f"Made by `python experiments/diagnose_heldout_ceiling.py {' '.join(args.cases)} "
             f"--max-zones {args.max_zones}" + "`.", "",
             "| case | set | kind | N | Ts s | true plant's validation fit % (per zone) | mean | noise std °C |",
             "|---|---|---|---|---|---|---|---|"]
    for spec in args.cases:
        i, s = map(int, spec.split(":"))
        c = H.draw_case(i, None, args.max_zones, s)
        T = c["n_est"] + c["n_val"]
        y0 = H.simulate(c, H.inputs(c, T))[c["n_est"]:]
        _, val = H.make_record(c)
        yv = np.asarray(val.y, float)
        e = yv - y0
        fit = 100 * (1 - np.linalg.norm(e, axis=0) / np.linalg.norm(yv - yv.mean(0), axis=0))
        lines.append(f"| {i:02d} | {s} | {c['kind']} | {c['zones']} | {c['ts']:.2f} | "
                     f"{', '.join(f'{v:.2f}' for v in fit)} | {fit.mean():.2f} | "
                     f"{', '.join(f'{v:.3f}' for v in e.std(0))} |")
    name = "diagnose_heldout_ceiling.md"
    atomic_write_text(Path(args.out) / name, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
