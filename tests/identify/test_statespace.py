"""State-space PEM: accuracy against the true model, stability, gradient, structure, errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.data import from_arrays
from jthermo.errors import ModelError
from jthermo.identify.statespace import (
    fit_statespace,
    ss_residuals,
    ss_residuals_level,
    ss_residuals_offset,
)
from jthermo.identify.subspace import n4sid
from jthermo.models import StateSpace, is_stable
from jthermo.models.statespace import InnovationsSS, pack, unpack

from ..helpers import central_difference

# a known 2-zone innovations model: slow thermal poles, cross-coupled heaters, coloured noise
A_TRUE = np.array([[0.93, 0.02], [0.03, 0.9]])
B_TRUE = np.array([[0.2, 0.05], [0.04, 0.25]])
C_TRUE = np.eye(2)
K_TRUE = np.array([[0.5, 0.1], [0.0, 0.4]])
NOISE = 0.05   # °C, innovation std


def _prbs(T, nu, rng):
    u = np.empty((T, nu))
    for j in range(nu):
        level, t = int(rng.integers(0, 2)), 0
        while t < T:
            hold = int(rng.integers(3, 16))
            u[t:t + hold, j] = 0.7 if level else 0.3
            t += hold
            level = 1 - level
    return u


def _data(T, seed):
    rng = np.random.default_rng(seed)
    u = _prbs(T, 2, rng)
    e = NOISE * rng.standard_normal((T, 2))
    x = np.zeros(2)
    y = np.empty((T, 2))
    for k in range(T):
        y[k] = 20.0 + C_TRUE @ x + e[k]
        x = A_TRUE @ x + B_TRUE @ (u[k] - 0.5) + K_TRUE @ e[k]
    return from_arrays(u, y)


def _fit_percent(y, yhat):
    return np.mean(100 * (1 - np.linalg.norm(y - yhat, axis=0)
                          / np.linalg.norm(y - y.mean(0), axis=0)))


@pytest.fixture(scope="module")
def fitted():
    est = _data(1500, 1)
    return est, fit_statespace(est, 2, n_starts=2, max_steps=50, focus="prediction")


def test_pem_fit_close_to_true_model(fitted):
    _, res = fitted
    val = _data(1500, 2)
    true = StateSpace(A_TRUE, B_TRUE, C_TRUE, K=K_TRUE, u0=np.full(2, 0.5), y0=np.full(2, 20.0))
    fit_true = _fit_percent(val.y, np.asarray(true.simulate(val.u)))
    fit_est = _fit_percent(val.y, np.asarray(res.model.simulate(val.u)))
    assert fit_est > fit_true - 1.0
    # the one-step cost reaches the noise floor
    assert res.cost < 1.1 * NOISE**2
    assert res.orders == {"n": 2}
    assert res.converged


def test_default_focus_is_simulation():
    """The default (`jthermo fit --model ss`) is an output-error fit: K = 0, and its simulation
    is within a point of the true model's on fresh data (OE is consistent under any noise)."""
    est, val = _data(1500, 1), _data(1500, 2)
    res = fit_statespace(est, 2, n_starts=2, max_steps=50)
    assert float(jnp.max(jnp.abs(res.model.K))) == 0.0
    true = StateSpace(A_TRUE, B_TRUE, C_TRUE, K=K_TRUE, u0=np.full(2, 0.5), y0=np.full(2, 20.0))
    fit_true = _fit_percent(val.y, np.asarray(true.simulate(val.u)))
    assert _fit_percent(val.y, np.asarray(res.model.simulate(val.u))) > fit_true - 1.0
    assert res.converged and is_stable(res.model)


def test_returned_model_is_stable_and_poles(fitted):
    _, res = fitted
    assert is_stable(res.model)
    est_poles = np.sort(np.abs(np.linalg.eigvals(np.asarray(res.model.A))))
    true_poles = np.sort(np.abs(np.linalg.eigvals(A_TRUE)))
    np.testing.assert_allclose(est_poles, true_poles, atol=0.02)
    # the predictor A - K C is stable too
    ss = res.model
    assert np.max(np.abs(np.linalg.eigvals(np.asarray(ss.A - ss.K @ ss.C)))) < 1.0
    assert np.all(np.isfinite(np.asarray(res.std)))


def test_stabilized_projects_unstable_model():
    ss = StateSpace(np.array([[1.05, 0.0], [0.1, 0.5]]), np.ones((2, 1)), np.eye(2))
    m = InnovationsSS.from_statespace(ss).stabilized()
    assert is_stable(m)


@pytest.mark.parametrize("residuals", ["x0", "x0_level", "level"])
def test_grad_matches_central_difference(residuals):
    data = _data(200, 3)
    ss, _ = n4sid(data, 2, horizon=5)
    template = InnovationsSS.from_statespace(ss)
    extra = {"x0": [0.1, -0.2], "x0_level": [0.1, -0.2, 0.05, 0.03], "level": [0.05, 0.03]}
    fn = {"x0": ss_residuals, "x0_level": ss_residuals_offset, "level": ss_residuals_level}
    theta = jnp.concatenate([pack(template), jnp.array(extra[residuals])])
    args = (template, jnp.asarray(data.y), jnp.asarray(data.u) - template.u0,
            jnp.asarray(data.w) - template.w0)

    def cost(th):
        return jnp.mean(fn[residuals](th, args) ** 2)

    f = jax.jit(cost)
    g = np.asarray(jax.grad(cost)(theta))
    g_fd = central_difference(f, np.asarray(theta))
    rel = np.linalg.norm(g - g_fd) / np.linalg.norm(g_fd)
    assert rel < 1e-6


def test_pack_unpack_roundtrip_and_canonical_basis():
    data = _data(300, 4)
    ss, _ = n4sid(data, 2, horizon=5)
    m = InnovationsSS.from_statespace(ss)
    assert m.fixed_c
    np.testing.assert_allclose(np.asarray(m.C), np.eye(2))
    # same transfer function after the change of basis
    np.testing.assert_allclose(np.asarray(m.dcgain()), np.asarray(ss.dcgain()), rtol=1e-9)
    m2 = unpack(pack(m), m)
    assert all(np.array_equal(a, b) for a, b in zip(m.free_leaves(), m2.free_leaves()))
    with pytest.raises(ModelError, match="unpack"):
        unpack(jnp.zeros(3), m)


def test_simulation_focus_and_errors():
    data = _data(400, 5)
    with pytest.raises(ModelError, match="focus"):
        fit_statespace(data, 2, focus="bogus")
    with pytest.raises(ModelError, match="positive integer"):
        fit_statespace(data, 0)
    with pytest.raises(ModelError, match="operating_point"):
        fit_statespace(data, 2, operating_point="bogus")
    m = InnovationsSS.from_statespace(n4sid(data, 2, horizon=5)[0], output_error=True)
    assert float(jnp.max(jnp.abs(m.K))) == 0.0
    assert m.n_params() == 4 + 4
