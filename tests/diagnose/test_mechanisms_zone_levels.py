"""The coupled simulation keeps each zone's own fitted surroundings offset (free level)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.diagnose import mechanisms as M
from tests.diagnose.records import prbs as _prbs


def _free_level_setup(mechs, n=3, T=300):
    lay = M.make_layout(n, n, M.n_drift_knots(T, 1.0))
    u = _prbs(T, n, 7)
    Th = np.stack([M.initial_theta(lay, log_a=np.log(0.01 + 0.004 * i), log_b=np.log(np.linspace(0.5, 0.1, n)),
                                   x0=60.0 + 3 * i, ts0=[-4.0, 1.0, 6.0][i]) for i in range(n)])
    f = {"u": jnp.asarray(u), "events": jnp.zeros((T, n)), "ts_level": 25.0, "ts_free": 1.0, "t_ref": 60.0,
         "wdev": jnp.zeros(T), "Phi": jnp.asarray(M.drift_basis(T, 1.0, lay.n_drift)),
         "delay": jnp.asarray(0.0), "u_pad": jnp.asarray(u.mean(0)), "ts": 1.0}
    rec = jnp.concatenate([jnp.asarray(Th[:, lay.sl("x0")][:, 0]), jnp.full(n, 25.0), jnp.zeros(lay.n_drift),
                           jnp.asarray([0.5])])
    return lay, Th, f, rec, jnp.asarray(M.on_vector(mechs))


@pytest.mark.parametrize("mechs", [[], ["radiative_loss", "heater_lag"]])
def test_uncoupled_zones_keep_their_own_level(mechs):
    """Nothing couples the zones: the coupled simulation is each zone's own model, whose
    surroundings are the common level plus the zone's offset plus the record's offset."""
    lay, Th, f, rec, on = _free_level_setup(mechs)
    T, n = f["u"].shape[0], lay.n
    Y = np.asarray(M.simulate_full(jnp.asarray(Th), on, f, lay, rec))
    for i in range(n):
        th = Th[i].copy()
        th[lay.sl("ts0")] += 0.5                    # the record's offset (rec's last entry)
        z = dict(f, ynb=jnp.zeros((T, n - 1)), ybar=jnp.zeros(T), events=jnp.zeros(T))
        yi = np.asarray(M.simulate_zone(jnp.asarray(th), on, z, lay))
        np.testing.assert_allclose(yi, Y[:, i], atol=1e-9)
    # the zones' offsets differ by 10 °C: one shared level would miss the ends by several °C
    assert np.ptp(Th[:, lay.sl("ts0")]) == 10.0


def test_zone_level_gradient_matches_central_differences():
    lay, Th, f, rec, on = _free_level_setup(["radiative_loss"])
    sl = lay.sl("ts0")

    @jax.jit
    def loss(off):
        th = jnp.asarray(Th).at[:, sl].set(off[:, None])
        return jnp.sum(M.simulate_full(th, on, f, lay, rec) ** 2) / 1e4

    off = jnp.asarray(Th[:, sl][:, 0])
    g = np.asarray(jax.grad(loss)(off))
    eps = 1e-5 * 10.0
    for i in range(lay.n):
        e = np.zeros(lay.n)
        e[i] = eps
        fd = (float(loss(off + e)) - float(loss(off - e))) / (2 * eps)
        np.testing.assert_allclose(g[i], fd, rtol=1e-6)
    assert np.all(np.abs(g) > 0)


def test_not_worse_needs_both_lower_mse_and_no_lower_mean_fit():
    from jthermo.diagnose.decide import not_worse

    rng = np.random.default_rng(3)
    T = 500
    y = np.stack([20.0 * np.sin(np.arange(T) / 40.0), 0.5 * np.sin(np.arange(T) / 25.0)], axis=1)
    e_ref = rng.normal(size=(T, 2)) * [2.0, 0.1]
    # much better on the wide output, worse on the quiet one: the pooled MSE falls, the mean fit falls
    e_new = rng.normal(size=(T, 2)) * [1.0, 0.3]
    assert np.mean(e_new ** 2) < np.mean(e_ref ** 2)
    assert not not_worse(y, e_new, e_ref)
    assert not_worse(y, 0.5 * e_ref, e_ref) and not_worse(y, e_ref, e_ref)
    assert not not_worse(y, 2.0 * e_ref, e_ref)
    assert not not_worse(y, np.full((T, 2), np.nan), e_ref)
