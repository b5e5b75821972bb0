"""The output level and the W1 fit gap to SIPPY (N = 4).

SIPPY fits the raw W1 data, i.e. it is handed the true output level 0 °C. jthermo's "rest"
operating point (which `offset="auto"` picks on W1) must estimate it. For ARX, ARMAX and OE,
seeds 0 and 1, this prints and writes the validation fit % with the rest level taken
(a) as jthermo does now (`estimate_rest_level`: the first 1 % of the samples less the response an
ARX model of the family's orders plus `REST_ARX_EXTRA` simulates for them), (b) from the first
sample alone (jthermo before 2026-11-23), (c) as the true 0 (what SIPPY assumes), and (d) as in (a) and then re-estimated after the fit
from the whole estimation-record simulation residual. Fits use the settings of
`benchmarks/identification.py` (OE: one denominator per output). Writes
experiments/results/identification_level_check.md (quoted in benchmarks/results/identification.md).

    .venv/bin/python experiments/identification_level_check.py
"""

from __future__ import annotations

import sys
import importlib
from contextlib import contextmanager
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import identification as bench  # noqa: E402

from jthermo.data import from_arrays  # noqa: E402

# the module whose `fit_polynomial` looks the rest-level estimate up
polymod = importlib.import_module("jthermo.identify.polynomial")
OUT = Path(__file__).resolve().parent / "results" / "identification_level_check.md"


@contextmanager
def rest_level(rule):
    """Temporarily replace jthermo's rest-level estimate by `rule(y)`."""
    saved = polymod.estimate_rest_level
    polymod.estimate_rest_level = lambda y, *a, **k: rule(y)
    try:
        yield
    finally:
        polymod.estimate_rest_level = saved


def main() -> None:
    bench.REST_LEVEL = None      # jthermo estimates the level (the benchmark passes W1's 0)
    W = bench.load_workloads()
    rows = []
    for seed in (0, 1):
        est, val = W.estimation_validation(4, 6000, seed)
        data = from_arrays(est["u"], est["y"])

        def fitted(family):
            res = bench.jthermo_fit(family, data, 4)
            return res, W.fit_percent(val["y"], bench.simulate_from_rest(res.model, val["u"]))

        for family in ("arx", "armax", "oe"):
            res, now = fitted(family)
            model = res.model
            level = np.mean(est["y"] - np.asarray(model.simulate(jnp.asarray(est["u"]))), axis=0)
            moved = eqx.tree_at(lambda m: m.y0, model, model.y0 + level)
            after = W.fit_percent(val["y"], bench.simulate_from_rest(moved, val["u"]))
            with rest_level(lambda y: y[0]):
                first = fitted(family)[1]
            with rest_level(lambda y: jnp.zeros_like(y[0])):
                true = fitted(family)[1]
            rows.append(f"| {seed} | {family} | {res.extra.get('offset')} | "
                        f"{np.round(np.asarray(model.y0), 3).tolist()} | "
                        f"{np.round(np.asarray(est['y'][0]), 3).tolist()} | {now:.3f} | "
                        f"{first:.3f} | {true:.3f} | {after:.3f} |")
            print(rows[-1], flush=True)
    header = ("| seed | family | offset | rest level used (a) | first sample (b) | fit % (a) | "
              "fit % (b) first sample | fit % (c) true level 0 | fit % (d) (a) re-levelled |")
    table = "\n".join([header, "|---|---|---|---|---|---|---|---|---|", *rows])
    OUT.write_text("# W1 (N = 4): the output level and the fit gap to SIPPY\n\n"
                   "Command: `.venv/bin/python experiments/identification_level_check.py`. "
                   "SIPPY (benchmarks/results/identification.md, seed 0): ARX 54.83, ARMAX 55.20, "
                   "OE 55.36.\n\n" + table + "\n")


if __name__ == "__main__":
    main()
