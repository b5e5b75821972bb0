"""Synthetic two-zone bed records with one concealed effect, for the diagnosis tests."""

import jax.numpy as jnp
import numpy as np

from jthermo.data import from_arrays
from jthermo.models.greybox import BedModel, ExtendedBedModel

T_EST, T_VAL = 900, 450
CAP = np.array([36.0, 40.0])
LOSS = np.array([0.6, 0.55])
GAIN = np.array([[35.0, 6.0], [5.0, 32.0]])
TS = 145.0      # °C, the surroundings
DELAY = 4       # samples of the concealed input delay


def prbs(T, n, seed):
    rng = np.random.default_rng(seed)
    u = np.empty((T, n))
    for j in range(n):
        t, level = 0, int(rng.integers(0, 2))
        while t < T:
            h = int(rng.integers(3, 16))
            u[t:t + h, j] = 0.7 if level else 0.3
            t += h
            level = 1 - level
    return u


def record(effect, seed, *, n_est=T_EST, n_val=T_VAL, ambient=True):
    """(estimation, validation) `IOData` of the bed with `effect` (None, "input_delay" or
    "lateral_conduction") concealed, 0.05 °C sensor noise, Ts = 1 s; with a constant measured
    `w_ambient` column, or (ambient=False) none, leaving the surroundings to be estimated."""
    T = n_est + n_val
    u = prbs(T, 2, seed)
    w = np.full((T, 1), TS)
    if effect == "lateral_conduction":
        model = ExtendedBedModel.from_physical(CAP, LOSS, GAIN, coupling=[0.25], edges=[(0, 1)])
    else:
        model = BedModel.from_physical(CAP, LOSS, GAIN)
    u_in = u
    if effect == "input_delay":
        u_in = np.concatenate([np.full((DELAY, 2), 0.5), u[:-DELAY]])
    x0 = jnp.asarray(TS + GAIN @ np.full(2, 0.5) / LOSS)
    y = np.asarray(model.simulate(u_in, w, x0=x0))
    y = y + 0.05 * np.random.default_rng(seed + 100).normal(size=y.shape)
    d = from_arrays(u, y, 1.0, w, signal_names=["ambient"]) if ambient else from_arrays(u, y, 1.0)
    w = np.asarray(d.w)
    return d.replace(u=u[:n_est], y=y[:n_est], w=w[:n_est]), d.replace(
        u=u[n_est:], y=y[n_est:], w=w[n_est:], t0=float(n_est))
