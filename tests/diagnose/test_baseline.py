"""`baseline.py`: the NumPy first-order baseline against the compiled mechanism-library fit and
simulation it replaces (`fitting.fit_zones` / `sim_zones` with every mechanism off)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.diagnose import baseline as B
from jthermo.diagnose import mechanisms as M
from jthermo.diagnose.fitting import fit_zones, sim_zones

jax.config.update("jax_enable_x64", True)

T, N, TS = 600, 2, 1.0


def _record(seed=0):
    """Two first-order zones (plus a little lag the baseline leaves out) on PRBS inputs, with
    0.03 °C noise, surroundings at 25 °C."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.integers(0, 2, size=(T // 15 + 1, N)), 15, axis=0)[:T] * 0.8
    a, b = np.array([0.004, 0.006]), np.array([[0.3, 0.04], [0.05, 0.25]])
    x = np.array([40.0, 35.0])
    y = np.empty((T, N))
    p = np.zeros(N)
    for k in range(T):
        y[k] = x
        p += 0.2 * (u[k] - p)
        x = x + TS * (-a * (x - 25.0) + b @ p)
    return y + 0.03 * rng.standard_normal((T, N)), u


@pytest.mark.parametrize("ts_free", [0.0, 1.0])
def test_numpy_baseline_matches_compiled_fit(ts_free):
    y, u = _record()
    level = 25.0 if not ts_free else 20.0
    lay = M.make_layout(N, N, M.n_drift_knots(T, TS))
    th0 = np.stack([M.initial_theta(lay, log_a=np.log(0.01), log_b=np.log([0.1, 0.1]), x0=y[0, i])
                    for i in range(N)])
    names = ["log_a", "log_b", "x0"] + (["ts0"] if ts_free else [])
    mask = lay.mask(names)
    u_pad = u.mean(axis=0)
    shared = {"u": jnp.asarray(u), "ts_level": jnp.asarray(level), "ts_free": jnp.asarray(ts_free),
              "wdev": jnp.zeros(T), "Phi": jnp.asarray(M.drift_basis(T, TS, lay.n_drift)),
              "u_pad": jnp.asarray(u_pad), "ts": jnp.asarray(TS), "t_ref": jnp.asarray(float(y.mean()))}
    per = {"y": jnp.asarray(y.T), "ynb": jnp.asarray(y[:, ::-1].T[:, :, None]),
           "ybar": jnp.asarray(np.tile(y.mean(axis=1), (N, 1))), "events": jnp.zeros((N, T)),
           "delay": jnp.zeros(N)}
    on = jnp.zeros((N, 8))
    th_lm, _, _ = fit_zones(jnp.asarray(th0), jnp.asarray(np.tile(mask, (N, 1))), on, per, shared, lay,
                            60, int(mask.sum()))
    yh_lm = np.asarray(sim_zones(th_lm, on, per, shared, lay)).T
    th_np = B.fit(th0, y, u, TS, level, ts_free, lay)
    yh_np = B.simulate(th_np, u, u_pad, TS, level, ts_free, lay)
    # the same optimum: costs equal to 1e-8, simulations to well under the noise
    c_lm, c_np = np.mean((y - yh_lm) ** 2, axis=0), np.mean((y - yh_np) ** 2, axis=0)
    np.testing.assert_allclose(c_np, c_lm, rtol=1e-8)
    assert np.all(c_np <= c_lm * (1 + 1e-10))
    np.testing.assert_allclose(yh_np, yh_lm, atol=1e-4)
    # untouched groups stay at the start
    free = np.concatenate([np.arange(lay.size)[lay.sl(nm)] for nm in names])
    np.testing.assert_array_equal(np.delete(th_np, free, axis=1), np.delete(th0, free, axis=1))
    # the NumPy simulation of the compiled fit's parameters equals the compiled simulation,
    # with and without a (fractional) dead time
    for d in (0.0, 2.5):
        per_d = {**per, "delay": jnp.full(N, d)}
        on_d = on.at[:, 4].set(1.0)
        ref = np.asarray(sim_zones(th_lm, on_d, per_d, shared, lay)).T
        np.testing.assert_allclose(B.simulate(np.asarray(th_lm), u, u_pad, TS, level, ts_free, lay, d), ref,
                                   atol=1e-8)
