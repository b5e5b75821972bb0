"""Scale: the grey-box bed fitted zone by zone, and the state-space PEM that
never forms a dense Jacobian over all outputs when it would not fit in memory."""

import jax.numpy as jnp
import numpy as np
import pytest

import jthermo.identify.statespace as ss_mod
from jthermo.data import from_arrays
from jthermo.errors import FitError
from jthermo.identify import matrix_free
from jthermo.identify.greybox import fit_greybox
from jthermo.models.greybox import BedModel


def _bed(n=4, T=1200, measured=True, seed=0):
    rng = np.random.default_rng(seed)
    loss = rng.uniform(4.0, 8.0, n)
    gain = 50.0 * np.eye(n) + 8.0 * (1 - np.eye(n))
    true = BedModel.from_physical(np.full(n, 1000.0), loss, gain)
    levels = rng.integers(0, 2, size=(T // 25 + 1, n)) * 0.6 + 0.2
    u = np.repeat(levels, 25, axis=0)[:T]
    w = 24.0 + 2.0 * np.sin(np.arange(T) / 200.0)[:, None] if measured else np.full((T, 1), 24.0)
    y = np.asarray(true.simulate(u, w, x0=jnp.full(n, 30.0)))
    y = y + 0.03 * rng.standard_normal(y.shape)
    return from_arrays(u, y, 1.0, w if measured else None), loss, gain


def test_greybox_per_zone_recovers_parameters():
    data, loss, gain = _bed()
    fit = fit_greybox(data)
    np.testing.assert_allclose(np.asarray(fit.model.loss), loss, rtol=0.03)
    np.testing.assert_allclose(np.asarray(fit.model.gain), gain, rtol=0.05)
    assert fit.converged
    n, nu = 4, 4
    # block-diagonal covariance over [log G, log n, x0]: no cross-zone terms
    cov = np.asarray(fit.covariance)
    assert cov.shape == (n + n * nu + n,) * 2
    assert cov[0, 1] == 0.0 and cov[0, n] != 0.0
    np.testing.assert_allclose(fit.x0, 30.0, atol=0.2)


def test_greybox_unmeasured_surroundings_shared():
    data, loss, _ = _bed(n=3, measured=False, seed=1)
    fit = fit_greybox(data)
    assert abs(float(fit.model.surroundings) - 24.0) < 0.5
    np.testing.assert_allclose(np.asarray(fit.model.loss), loss, rtol=0.05)


def test_greybox_zones_are_separate_problems():
    """Zone i's fit depends on its own temperature only (the zones share no state): changing
    zone 0's record leaves the other zones' parameters exactly as they were."""
    data, _, _ = _bed(n=3, T=600)
    base = fit_greybox(data)
    y = np.asarray(data.y).copy()
    y[:, 0] += 0.2 * np.sin(np.arange(y.shape[0]) / 30.0)
    other = fit_greybox(from_arrays(data.u, y, 1.0, data.w))
    assert float(other.model.log_loss[0]) != float(base.model.log_loss[0])
    np.testing.assert_array_equal(np.asarray(other.model.log_loss[1:]),
                                  np.asarray(base.model.log_loss[1:]))
    np.testing.assert_array_equal(np.asarray(other.model.log_gain[1:]),
                                  np.asarray(base.model.log_gain[1:]))


def _ss_data(n=3, T=1500, seed=0):
    rng = np.random.default_rng(seed)
    a = np.array([0.95, 0.9, 0.93])[:n]
    B = 0.1 * (np.eye(n) + 0.3)
    u = np.repeat(rng.integers(0, 2, size=(T // 10 + 1, n)) * 1.0, 10, axis=0)[:T]
    x = np.zeros((T, n))
    for k in range(T - 1):
        x[k + 1] = a * x[k] + B @ u[k]
    return from_arrays(u, x + 0.02 * rng.standard_normal((T, n)), 1.0)


def test_ss_large_problem_is_matrix_free(monkeypatch):
    """Above the dense-Jacobian budget the dense solver (which forms the (T·ny, p) Jacobian)
    is never called; the matrix-free solve reaches the dense solve's cost."""
    data = _ss_data()
    dense = ss_mod.fit_statespace(data, 3, operating_point="mean", n_starts=1,
                                  focus="simulation", coupling="full")
    monkeypatch.setattr(ss_mod, "DENSE_JACOBIAN_BYTES", 0)

    def forbidden(*a, **k):
        raise AssertionError("dense minimize called on a large problem")

    monkeypatch.setattr(ss_mod, "minimize", forbidden)
    free = ss_mod.fit_statespace(data, 3, operating_point="mean", n_starts=4,
                                 focus="simulation", coupling="full")
    assert free.cost <= dense.cost * (1 + 1e-3)
    assert free.converged
    assert np.all(np.isnan(np.asarray(free.std)))      # no covariance without the Jacobian


def test_matrix_free_honest_flags():
    def resid(theta, args):
        return (args - jnp.exp(theta[0]) * jnp.arange(5.0) - theta[1])[:, None]

    y = 2.0 * jnp.arange(5.0) + 1.0
    res = matrix_free.minimize_matrix_free(resid, jnp.array([0.0, 0.0]), y, max_steps=50)
    np.testing.assert_allclose(np.asarray(res.theta), [np.log(2.0), 1.0], atol=1e-6)
    assert bool(res.converged)
    cut = matrix_free.minimize_matrix_free(resid, jnp.array([3.0, 0.0]), y, max_steps=1)
    assert not bool(cut.converged)                        # the step cap is not convergence
    with pytest.raises(FitError):
        matrix_free.minimize_matrix_free(resid, jnp.array([800.0, 0.0]), y)
