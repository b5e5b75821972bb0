"""Timing of the validation tools on the W1 workload's shapes (N zones, T = 6000), cold and warm.

Run: .venv/bin/python benchmarks/validate_speed.py [N]
Prints JSON: seconds for compare (simulation fit with least-squares x0), residual_tests,
spectral_estimate, and the fit of the true plant on its own noisy validation data.
"""

import json
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from jthermo import StateSpace, validate
from jthermo.data import from_arrays
from jthermo.inputs import prbs


def main(N=4, T=6000, seed=0):
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.92, 0.96, N)
    rows = max(1, int(np.floor(np.sqrt(N))))
    cols = int(np.ceil(N / rows))
    P = np.stack([np.arange(N) // cols, np.arange(N) % cols], 1).astype(float)
    d2 = ((P[:, None] - P[None]) ** 2).sum(-1)
    B = rng.uniform(0.15, 0.25, N)[:, None] * np.exp(-d2 / 0.8)
    m = StateSpace(np.diag(a), B, np.eye(N), ts=1.0)
    u = np.asarray(prbs(seed, T, N))
    y = np.asarray(m.simulate(u)) + 0.1 * rng.standard_normal((T, N))
    data = from_arrays(u, y)
    out = {"N": N, "T": T}
    for name, fn in [("compare", lambda: validate.compare(m, data)),
                     ("residual_tests", lambda: validate.residual_tests(m, data)),
                     ("spectral_estimate", lambda: validate.spectral_estimate(data))]:
        t0 = time.perf_counter()
        r = fn()
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = fn()
        warm = time.perf_counter() - t0
        out[name] = {"cold_s": round(cold, 3), "warm_s": round(warm, 3)}
        if name == "compare":
            out["true_model_mean_fit_percent"] = round(r["mean_fit_percent"], 2)
    print(json.dumps(out))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 4)
