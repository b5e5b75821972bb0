"""W1 N4SID fit % against the subspace weighting (CVA, MOESP) and the Hankel horizon (block
rows; None = `default_horizon`, 10 here), N = 4 and 16: what the 0.6-0.7 point N4SID gap to
SIPPY (benchmarks/results/identification.md) depends on. Prints `N weighting horizon fit%`.

    .venv/bin/python experiments/n4sid_horizon_check.py
"""
import sys
import jax
jax.config.update("jax_enable_x64", True)
import numpy as np
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1] / "benchmarks"))
import identification as bi
from jthermo.identify.subspace import n4sid
from jthermo.data import from_arrays
W = bi.load_workloads()
for N in (4, 16):
    est, val = W.estimation_validation(N, 6000)
    d = from_arrays(est["u"], est["y"])
    for w in ("cva", "moesp"):
        for h in (None, 10, 20, 40):
            try:
                m = n4sid(d, N, h, weighting=w)[0]
                print(N, w, h, round(W.fit_percent(val["y"], bi.simulate_from_rest(m, val["u"])), 3), flush=True)
            except Exception as e:
                print(N, w, h, "ERR", e)
