"""Does the W1 fit gap to SIPPY (0.1–0.2 points at N = 4) come from the output level?

Fits ARX, ARMAX and OE on the W1 workload (N = 4, seeds 0 and 1) with jthermo's defaults,
then re-estimates the output level from the whole estimation-record simulation residual and
prints the validation fit % before and after (benchmarks/results/identification.md, notes).

    .venv/bin/python experiments/identification_level_check.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import identification as bench  # noqa: E402

from jthermo.data import from_arrays  # noqa: E402
from jthermo.identify.fit import fit  # noqa: E402


def main() -> None:
    W = bench.load_workloads()
    for seed in (0, 1):
        est, val = W.estimation_validation(4, 6000, seed)
        data = from_arrays(est["u"], est["y"])
        for family in ("arx", "armax", "oe"):
            res = fit(data, family, bench.JT_ORDERS[family], n_starts=4)
            model = res.model
            before = W.fit_percent(val["y"], bench.simulate_from_rest(model, val["u"]))
            level = np.mean(est["y"] - np.asarray(model.simulate(jnp.asarray(est["u"]))), axis=0)
            moved = eqx.tree_at(lambda m: m.y0, model, model.y0 + level)
            after = W.fit_percent(val["y"], bench.simulate_from_rest(moved, val["u"]))
            print(f"seed {seed} {family:6s} offset={res.extra.get('offset')}: fit {before:.3f} % "
                  f"-> {after:.3f} % with the level re-estimated (shift {np.round(level, 3)})",
                  flush=True)


if __name__ == "__main__":
    main()
