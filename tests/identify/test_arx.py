import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.errors import DataError, ModelError
from jthermo.identify.arx import arx_ls, first_row, perturb_starts
from jthermo.models.polynomial import ARX


def _numpy_regressors(y, u, na, nb, nk, i, full):
    """Independent construction of output i's ARX regression, rows n0..T-1."""
    T, ny = y.shape
    n0 = max(na, nk + nb - 1)
    rows = []
    for t in range(n0, T):
        src = range(ny) if full else [i]
        r = [-y[t - k, l] for l in src for k in range(1, na + 1)]
        r += [u[t - nk - k, j] for j in range(u.shape[1]) for k in range(nb)]
        rows.append(r)
    return np.array(rows), y[n0:, i]


@pytest.mark.parametrize("full", [False, True])
def test_arx_equals_numpy_lstsq(full):
    rng = np.random.default_rng(0)
    T, ny, nu, na, nb, nk = 300, 3, 2, 2, 3, 1
    u = rng.standard_normal((T, nu))
    y = np.cumsum(rng.standard_normal((T, ny)), axis=0) * 0.1 + u @ rng.standard_normal((nu, ny))
    res = arx_ls(jnp.asarray(y), jnp.asarray(u), na, nb, nk, full_a=full)
    coef = np.asarray(res.model.flat_coefficients())
    for i in range(ny):
        Phi, target = _numpy_regressors(y, u, na, nb, nk, i, full)
        ref = np.linalg.lstsq(Phi, target, rcond=None)[0]
        np.testing.assert_allclose(coef[i], ref, atol=1e-9, rtol=0)
    assert first_row(na, nb, nk) == 3


def test_arx_recovers_noiseless_and_offset():
    rng = np.random.default_rng(1)
    true = ARX(np.array([[-0.9], [-0.8]]), rng.standard_normal((2, 2, 2)), nk=1,
               y0=[25.0, 30.0])
    u = rng.uniform(0, 1, (400, 2))
    y = true.simulate(u)
    res = arx_ls(y - y[0], jnp.asarray(u), 1, 2, 1, offset=True, y0=y[0])
    np.testing.assert_allclose(res.model.flat_coefficients(), true.flat_coefficients(), atol=1e-9)
    np.testing.assert_allclose(res.model.y0, true.y0, atol=1e-7)
    np.testing.assert_allclose(res.model.simulate(u), y, atol=1e-6)


def test_arx_three_sigma_covers_truth():
    rng = np.random.default_rng(2)
    true = ARX(np.array([[-1.2, 0.5]]), np.array([[[0.5, 0.3]]]), nk=2)
    u = rng.standard_normal((2000, 1))
    e = 0.1 * rng.standard_normal((2000, 1))
    # ARX data: A y = B u + e  <=>  innovations with the ARX noise model
    ss = true.to_statespace()
    x = np.zeros(ss.A.shape[0])
    y = np.zeros((2000, 1))
    for t in range(2000):
        y[t] = ss.C @ x + e[t]
        x = ss.A @ x + ss.B @ u[t] + ss.K @ e[t]
    res = arx_ls(jnp.asarray(y), jnp.asarray(u), 2, 2, 2)
    err = np.abs(np.asarray(res.model.flat_coefficients() - true.flat_coefficients()))
    assert np.all(err < 3 * np.asarray(res.std))
    assert np.all(np.asarray(res.std) < 0.05)


def test_arx_errors_and_starts():
    y = jnp.zeros((20, 1))
    with pytest.raises(ModelError, match="impossible"):
        arx_ls(y, y, 0, 0, 1)
    with pytest.raises(DataError, match="too few"):
        arx_ls(y, y, 5, 10, 1)
    s = perturb_starts(np.ones((2, 3)), 4, seed=0)
    assert s.shape == (2, 4, 3)
    np.testing.assert_array_equal(s[:, 0], np.ones((2, 3)))
    np.testing.assert_array_equal(s, perturb_starts(np.ones((2, 3)), 4, seed=0))
