"""The demo's fits stage with each PEM engine: does `engine="auto"` (the default) change it?

`jthermo demo` fits ARMAX, OE and BJ at fixed orders (`demo.FAMILY_ORDERS`) on a 4-zone virtual
printer record (`demo.SETTINGS["full"]`: 3600 + 1800 s, seed 0, 4 starts). For each family and
engine (`jax`: the compiled PEM, the default before `auto`; `numpy`; `auto`): the engine that
ran, the validation fit % per output and mean (`validate.compare`, as the demo reports it),
the estimation cost V (mean squared prediction error, what PEM minimises), CPU s of the fit.

    python experiments/polynomial_engine_demo_fits.py
    -> experiments/results/polynomial_engine_demo_fits.md
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
ENGINES = ("jax", "numpy", "auto")


def main() -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    from jthermo.data import atomic_write_text
    from jthermo.demo import FAMILY_ORDERS, ID_EFFECTS, SETTINGS
    from jthermo.identify.fit import fit
    from jthermo.printer import generate, make_printer
    from jthermo.validate import compare

    cfg, seed = SETTINGS["full"], 0
    plant = make_printer(cfg["zones"], ID_EFFECTS, seed=seed)
    est = generate(plant, "prbs", cfg["est_s"], seed=seed)
    val = generate(plant, "prbs", cfg["val_s"], seed=seed + 1)
    lines = ["# The demo's ARMAX / OE / BJ fits with each PEM engine", "",
             ("`python experiments/polynomial_engine_demo_fits.py`: `jthermo demo`'s records and "
              "orders (4 zones, 3600 + 1800 s, seed 0, 4 starts). fit % = validation fit as the "
              "demo reports it; V = estimation cost (mean squared prediction error, what PEM "
              f"minimises). Load (1-minute) at the start: {os.getloadavg()[0]:.1f}."), "",
             "| family | engine | ran | fit % (mean) | per output | V | CPU s |",
             "|---|---|---|---|---|---|---|"]
    for fam in ("armax", "oe", "bj"):
        for eng in ENGINES:
            t0 = time.process_time()
            res = fit(est, fam, FAMILY_ORDERS[fam], seed=seed, n_starts=cfg["n_starts"],
                      engine=eng)
            cpu = time.process_time() - t0
            cmp = compare(res.model, val)
            per = " / ".join(f"{float(f):.3f}" for f in cmp["fit_percent"])
            lines.append(f"| {fam.upper()} | {eng} | {res.extra['engine']} | "
                         f"{cmp['mean_fit_percent']:.4f} | {per} | {res.cost:.8f} | {cpu:.2f} |")
            print(lines[-1], flush=True)
    atomic_write_text(ROOT / "experiments" / "results" / "polynomial_engine_demo_fits.md",
                      "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
