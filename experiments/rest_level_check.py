"""Error of the "rest" output-level estimate against the extra ARX orders it uses.

`jthermo.identify.operating_point.estimate_rest_level` averages the first 1 % of the samples
less the response an ARX model simulates for them; the ARX orders are the family's (here first
order, nk = 1) plus `REST_ARX_EXTRA`. On data whose true level is 0 °C this prints and writes
the estimated level (mean over outputs, and RMS over outputs and seeds) for 0..5 extra orders, on W1 (N = 4 and
16, coloured noise; what SIPPY is handed as known) and on the OE data of
`experiments/identification_coverage.py` (N = 4, white output noise), seeds 0-2.

    .venv/bin/python experiments/rest_level_check.py

Writes experiments/results/rest_level_check.md.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "experiments"))
import identification as bench  # noqa: E402
import identification_coverage as coverage  # noqa: E402

from jthermo.models.polynomial import as_nk  # noqa: E402

opmod = importlib.import_module("jthermo.identify.operating_point")
EXTRAS = (0, 1, 2, 3, 4, 5)
SEEDS = (0, 1, 2)


def level(y, u, extra):
    saved = opmod.REST_ARX_EXTRA
    opmod.REST_ARX_EXTRA = extra
    try:
        N = y.shape[1]
        return np.asarray(opmod.estimate_rest_level(jnp.asarray(y), jnp.asarray(u), 1,
                                                    as_nk(1, N, N), 1, False, 1.0))
    finally:
        opmod.REST_ARX_EXTRA = saved


def main() -> None:
    W = bench.load_workloads()
    sets = {f"W1 N = {N}": [(lambda N=N, s=s: W.estimation_validation(N, 6000, s)[0])
                            for s in SEEDS] for N in (4, 16)}
    sets["OE data N = 4"] = [(lambda s=s: dict(zip(("u", "y"), coverage.dataset("oe", 6000, s, 1))))
                             for s in SEEDS]
    rows = []
    for name, makers in sets.items():
        data = [m() for m in makers]
        for extra in EXTRAS:
            levels = [level(d["y"], d["u"], extra) for d in data]
            means = ", ".join(f"{lv.mean():+.3f}" for lv in levels)
            rms = float(np.sqrt(np.mean(np.concatenate(levels) ** 2)))
            rows.append(f"| {name} | {extra} | {means} | {rms:.3f} |")
            print(rows[-1], flush=True)
    text = "\n".join([
        "# The rest-level estimate against the extra ARX orders", "",
        "Command: `.venv/bin/python experiments/rest_level_check.py`. True level 0 °C on every "
        f"record. Estimated level: mean over outputs per seed ({', '.join(map(str, SEEDS))}); "
        f"RMS over outputs and seeds. jthermo uses {opmod.REST_ARX_EXTRA} extra orders "
        "(`REST_ARX_EXTRA`).", "",
        "| data | extra ARX orders | mean level per seed (°C) | RMS level error (°C) |",
        "|---|---|---|---|", *rows, ""])
    (ROOT / "experiments" / "results" / "rest_level_check.md").write_text(text)


if __name__ == "__main__":
    main()
