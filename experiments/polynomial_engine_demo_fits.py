"""The demo's fits stage with each PEM engine: does `engine="auto"` (the default) change it?

`jthermo demo` fits ARMAX, OE and BJ at fixed orders (`demo.FAMILY_ORDERS`) on a 4-zone virtual
printer record (`demo.SETTINGS["full"]`: 3600 + 1800 s, seed 0, 4 starts); `--seeds` adds other
printer seeds (the demo's recipe with that seed), `--engines` / `--families` select;
`--jax-draws`: every engine starts from the compiled engine's start points (`jax.random`
draws; the NumPy engine's own are NumPy's `default_rng`), to separate the effect of the start
points from that of the solver. For each family and
engine (`jax`: the compiled PEM, the default before `auto`; `numpy`; `auto`): the engine that
ran, the validation fit % per output and mean (`validate.compare`, as the demo reports it),
the estimation cost V (mean squared prediction error, what PEM minimises), CPU s of the fit.

    python experiments/polynomial_engine_demo_fits.py [--seeds 0 1 2] [--engines jax auto]
       
    -> experiments/results/polynomial_engine_demo_fits.md
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
ENGINES = ("jax", "numpy", "auto")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--engines", nargs="+", default=list(ENGINES), choices=ENGINES)
    ap.add_argument("--families", nargs="+", default=["armax", "oe", "bj"],
                    choices=("armax", "oe", "bj"))
    ap.add_argument("--jax-draws", action="store_true")
    args = ap.parse_args(argv)
    command = "python experiments/polynomial_engine_demo_fits.py " + " ".join(argv or sys.argv[1:])
    import jax

    jax.config.update("jax_enable_x64", True)
    from jthermo.data import atomic_write_text
    from jthermo.demo import ID_EFFECTS, SETTINGS
    from jthermo.identify.fit import fit
    from jthermo.printer import generate, make_printer
    from jthermo.validate import compare

    if args.jax_draws:
        from jthermo.identify import arx, polynomial

        own = arx.perturb_starts
        polynomial.perturb_starts = lambda th, n, seed, **kw: own(th, n, seed, draws="jax")
    cfg = SETTINGS["full"]
    lines = ["# The demo's ARMAX / OE / BJ fits with each PEM engine", "",
             (f"`{command.strip()}`: `jthermo demo`'s records and orders (4 zones, "
              "3600 + 1800 s, 4 starts; seed 0 is the demo's). fit % = validation fit as the "
              "demo reports it; V = estimation cost (mean squared prediction error, what PEM "
              f"minimises). Load (1-minute) at the start: {os.getloadavg()[0]:.1f}."), "",
             f"Start points: {'the compiled engine’s (jax.random) for every engine' if args.jax_draws else 'each engine’s own'}.", "",
             "| seed | family | engine | ran | fit % (mean) | per output | V | CPU s |",
             "|---|---|---|---|---|---|---|---|"]
    for seed in args.seeds:
        plant = make_printer(cfg["zones"], ID_EFFECTS, seed=seed)
        est = generate(plant, "prbs", cfg["est_s"], seed=seed)
        val = generate(plant, "prbs", cfg["val_s"], seed=seed + 1)
        lines += _rows(fit, compare, est, val, cfg, seed, args.families, args.engines)
    atomic_write_text(ROOT / "experiments" / "results" / "polynomial_engine_demo_fits.md",
                      "\n".join(lines) + "\n")
    return 0


def _rows(fit, compare, est, val, cfg, seed, families, engines) -> list[str]:
    from jthermo.demo import FAMILY_ORDERS

    lines = []
    for fam in families:
        for eng in engines:
            t0 = time.process_time()
            res = fit(est, fam, FAMILY_ORDERS[fam], seed=seed, n_starts=cfg["n_starts"],
                      engine=eng)
            cpu = time.process_time() - t0
            cmp = compare(res.model, val)
            per = " / ".join(f"{float(f):.3f}" for f in cmp["fit_percent"])
            lines.append(f"| {seed} | {fam.upper()} | {eng} | {res.extra['engine']} | "
                         f"{cmp['mean_fit_percent']:.4f} | {per} | {res.cost:.8f} | {cpu:.2f} |")
            print(lines[-1], flush=True)
    return lines


if __name__ == "__main__":
    sys.exit(main())
