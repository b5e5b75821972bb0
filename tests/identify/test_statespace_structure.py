"""State space with one state per output: the diagonal-A structure and the coupling hold-out."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.data import from_arrays
from jthermo.errors import ModelError
from jthermo.identify.statespace import (
    diagonal_residual,
    diagonal_theta,
    fit_statespace,
)
from jthermo.identify.subspace import n4sid
from jthermo.inputs import prbs
from jthermo.models.statespace import InnovationsSS

from ..helpers import central_difference


def _bed(A, T=1500, seed=0):
    """3 outputs, states = outputs, dense heater gains, AR(1) sensor noise and slow drift."""
    rng = np.random.default_rng(seed)
    B = np.array([[0.3, 0.1, 0.02], [0.1, 0.3, 0.1], [0.02, 0.1, 0.3]])
    u = np.asarray(prbs(seed, T, 3, levels=(0.2, 0.8), hold=(5, 30)))
    x = np.zeros(3)
    y = np.empty((T, 3))
    v = np.zeros(3)
    for k in range(T):
        v = 0.7 * v + 0.05 * rng.standard_normal(3)
        y[k] = 30.0 + x + v
        x = A @ x + B @ (u[k] - 0.5) + 0.01 * rng.standard_normal(3)
    return from_arrays(u, y)


DIAGONAL = np.diag([0.95, 0.96, 0.94])
COUPLED = np.array([[0.90, 0.05, 0.0], [0.05, 0.88, 0.05], [0.0, 0.05, 0.90]])


def _bed_at_rest(A, T=800, seed=0):
    """As `_bed` but from rest with zero input (x0 = 0, the model in absolute inputs)."""
    rng = np.random.default_rng(seed)
    B = np.array([[0.3, 0.1, 0.02], [0.1, 0.3, 0.1], [0.02, 0.1, 0.3]])
    u = np.asarray(prbs(seed, T, 3, levels=(0.2, 0.8), hold=(5, 30)))
    x, v = np.zeros(3), np.zeros(3)
    y = np.empty((T, 3))
    for k in range(T):
        v = 0.7 * v + 0.05 * rng.standard_normal(3)
        y[k] = 30.0 + x + v
        x = A @ x + B @ u[k]
    return from_arrays(u, y)


@pytest.mark.parametrize("theta", [[0.9, 0.2, -0.1, 0.05, 0.3, -0.2],   # x0 estimated
                                   [0.9, 0.2, -0.1, 0.05, -0.2]])       # x0 = 0
def test_diagonal_residual_gradient_matches_central_difference(theta):
    rng = np.random.default_rng(1)
    args = {"y": jnp.asarray(rng.standard_normal(80)),
            "du": jnp.asarray(rng.standard_normal((80, 2))),
            "dw": jnp.asarray(rng.standard_normal((80, 1)))}
    theta = jnp.array(theta)

    def cost(th):
        return jnp.mean(diagonal_residual(th, args) ** 2)

    g = np.asarray(jax.grad(cost)(theta))
    g_fd = central_difference(jax.jit(cost), np.asarray(theta))
    assert np.linalg.norm(g - g_fd) / np.linalg.norm(g_fd) < 1e-6


def test_diagonal_theta_layout_and_covariance():
    data = _bed(DIAGONAL, T=800)
    tpl = InnovationsSS.from_statespace(n4sid(data, 3)[0], output_error=True)
    y, du, dw = (jnp.asarray(data.y), jnp.asarray(data.u) - tpl.u0,
                 jnp.asarray(data.w) - tpl.w0)
    theta, res, cov = diagonal_theta(tpl, y, du, dw)
    A = np.asarray(theta[:9]).reshape(3, 3)
    np.testing.assert_allclose(np.diag(A), np.asarray(res.theta[:, 0]))
    assert np.all(A[~np.eye(3, dtype=bool)] == 0.0)
    np.testing.assert_allclose(np.diag(A), np.diag(DIAGONAL), atol=0.02)
    var = np.diag(cov)
    assert np.all(var[:9][~np.eye(3, dtype=bool).ravel()] == 0.0)   # fixed off-diagonal A
    assert np.all(var[:9][np.eye(3, dtype=bool).ravel()] > 0.0)
    assert cov.shape == (theta.size, theta.size) and np.all(var[9:] > 0.0)


@pytest.mark.parametrize("A, chosen", [(DIAGONAL, "diagonal"), (COUPLED, "full")])
def test_auto_coupling_follows_the_data(A, chosen):
    r = fit_statespace(_bed(A), 3, max_steps=60)
    assert r.extra["coupling"] == chosen
    hold = r.extra["coupling_holdout"]
    assert (hold["full"] < hold["diagonal"]) == (chosen == "full")
    fitted = np.asarray(r.extra["parametrised"].A)
    if chosen == "full":   # the coupling is found, not just allowed
        assert np.min(fitted[[0, 1, 1, 2], [1, 0, 2, 1]]) > 0.02


def test_coupling_option_errors_and_full_is_the_earlier_path():
    data = _bed(DIAGONAL, T=600)
    with pytest.raises(ModelError, match="coupling"):
        fit_statespace(data, 3, coupling="sparse")
    r = fit_statespace(data, 3, coupling="full", n_starts=1, max_steps=30)
    assert r.extra["coupling"] == "full" and "coupling_holdout" not in r.extra


def test_rest_coupling_fits_diagonal_a_from_rest():
    """Rest mode (x0 = 0): `rest_coupling="diagonal"` fits the diagonal structure with x0 = 0
    in `ss_residuals_level`'s layout; it recovers A and, being the true structure, fits within
    2 % of the full-A path's (nesting) estimation cost, at the noise floor (AR(1) variance
    0.0049)."""
    data = _bed_at_rest(DIAGONAL)
    tpl = InnovationsSS.from_statespace(n4sid(data, 3, operating_point="rest")[0],
                                        output_error=True)
    y, du = jnp.asarray(data.y), jnp.asarray(data.u) - tpl.u0
    theta, res, cov = diagonal_theta(tpl, y, du, jnp.asarray(data.w) - tpl.w0, free_x0=False)
    assert theta.size == tpl.n_params() + 3 and cov.shape == (theta.size, theta.size)
    assert res.theta.shape == (3, 2 + 3)    # [a, b (3), dy0]: no x0 column
    diag = fit_statespace(data, 3, operating_point="rest", rest_coupling="diagonal",
                          max_steps=60)
    assert diag.extra["coupling"] == "diagonal" and np.all(np.asarray(diag.x0) == 0.0)
    np.testing.assert_allclose(np.diag(np.asarray(diag.extra["parametrised"].A)),
                               np.diag(DIAGONAL), atol=0.01)
    full = fit_statespace(data, 3, operating_point="rest", rest_coupling="full", n_starts=1,
                          max_steps=60)
    assert full.extra["coupling"] == "full"
    assert full.cost <= diag.cost < 1.02 * full.cost and diag.cost < 0.0049 * 1.05


def test_rest_coupling_default_option_errors_and_full_coupling_overrides_it():
    data = _bed_at_rest(DIAGONAL, T=600)
    with pytest.raises(ModelError, match="rest_coupling"):
        fit_statespace(data, 3, rest_coupling="sparse")
    r = fit_statespace(data, 3, max_steps=30)     # the default: rest mode, hold-out decides
    assert r.extra["operating_point"] == "rest" and r.extra["coupling"] == "diagonal"
    assert set(r.extra["coupling_holdout"]) == {"diagonal", "full"}
    r = fit_statespace(data, 3, operating_point="rest", coupling="full", rest_coupling="auto",
                       n_starts=1, max_steps=30)
    assert r.extra["coupling"] == "full" and "coupling_holdout" not in r.extra
