"""Does the W1 fit gap to SIPPY (0.1–0.2 points at N = 4) come from the output level?

Fits ARX, ARMAX and OE on the W1 workload (N = 4, seeds 0 and 1) with jthermo's defaults
(`offset="auto"`, which picks "rest": the level is the first, noisy, sample) and reports the
validation fit %: (a) as fitted; (b) with the level re-estimated afterwards from the whole
estimation-record simulation residual; (c) refitted with the rest level set to the true one
(0 °C: what SIPPY assumes when it fits the raw data). Writes
experiments/results/identification_level_check.md (quoted in benchmarks/results/identification.md).

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


OUT = Path(__file__).resolve().parent / "results" / "identification_level_check.md"


def main() -> None:
    W = bench.load_workloads()
    rows = []
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
            y_true_level = np.array(est["y"])
            y_true_level[0] = 0.0          # "rest" then takes the true level, 0
            refit = fit(from_arrays(est["u"], y_true_level), family, bench.JT_ORDERS[family],
                        n_starts=4, offset="rest")
            true = W.fit_percent(val["y"], bench.simulate_from_rest(refit.model, val["u"]))
            rows.append(f"| {seed} | {family} | {res.extra.get('offset')} | "
                        f"{np.round(np.asarray(est['y'][0]), 3).tolist()} | {before:.3f} | "
                        f"{after:.3f} | {true:.3f} |")
            print(rows[-1], flush=True)
    header = ("| seed | family | offset | first sample (level used) | fit % as fitted | "
              "level re-estimated after the fit | refitted at the true level 0 |")
    table = "\n".join([header, "|---|---|---|---|---|---|---|", *rows])
    OUT.write_text("# W1 (N = 4): the output level and the fit gap to SIPPY\n\n"
                   "Command: `.venv/bin/python experiments/identification_level_check.py`.\n\n"
                   + table + "\n")


if __name__ == "__main__":
    main()
