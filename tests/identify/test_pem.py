import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.errors import ConfigError, FitError
from jthermo.identify import pem

_TRACES = {"n": 0}


def _linear_residual(theta, args):
    X, y = args
    _TRACES["n"] += 1          # runs only while tracing
    return (y - X @ theta)[:, None]


def _rosen_residual(theta, args):
    # Rosenbrock as least squares: several local behaviours, minimum at (1, 1)
    return jnp.stack([10.0 * (theta[1] - theta[0] ** 2), 1.0 - theta[0]])[None, :]


def _double_well(theta, args):
    # minima at theta = 1.2 (cost 0) and near theta = -1 (cost about 0.125)
    t = theta[0]
    return jnp.stack([(t - 1.2) * (t + 1.0), jnp.where(t < 0, 0.5, 0.0)])[None, :]


@pytest.fixture(scope="module")
def linear_problem():
    rng = np.random.default_rng(0)
    X = rng.standard_normal((400, 3))
    y = X @ np.array([1.0, -2.0, 0.5]) + 0.1 * rng.standard_normal(400)
    return jnp.asarray(X), jnp.asarray(y)


@pytest.mark.parametrize("solver", ["lm", "gn"])
def test_linear_matches_lstsq_and_covariance(linear_problem, solver):
    X, y = linear_problem
    res = pem.minimize(_linear_residual, jnp.zeros(3), (X, y), solver=solver)
    ref, rss, *_ = np.linalg.lstsq(np.asarray(X), np.asarray(y), rcond=None)
    np.testing.assert_allclose(res.theta, ref, atol=1e-9)
    assert bool(res.converged)
    sigma2 = rss[0] / (len(y) - 3)
    cov = sigma2 * np.linalg.inv(np.asarray(X).T @ np.asarray(X))
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-8)
    np.testing.assert_allclose(res.std, np.sqrt(np.diag(cov)), rtol=1e-8)
    np.testing.assert_allclose(res.cost, rss[0] / len(y), rtol=1e-10)


def test_adam(linear_problem):
    X, y = linear_problem
    res = pem.minimize(_linear_residual, jnp.zeros(3), (X, y), solver="adam", max_steps=1500,
                       learning_rate=0.05)
    ref = np.linalg.lstsq(np.asarray(X), np.asarray(y), rcond=None)[0]
    np.testing.assert_allclose(res.theta, ref, atol=1e-4)


def test_no_retrace_same_shapes(linear_problem):
    X, y = linear_problem
    pem.minimize(_linear_residual, jnp.zeros((2, 3)), (X, y))
    n = _TRACES["n"]
    pem.minimize(_linear_residual, jnp.ones((2, 3)), (X, 2.0 * y))
    assert _TRACES["n"] == n


def test_multistart_picks_best():
    starts = jnp.array([[-1.5], [1.5], [-0.8]])
    res = pem.minimize(_double_well, starts, None)
    assert float(res.theta[0]) == pytest.approx(1.2, abs=1e-6)
    assert int(res.best_start) == 1
    assert float(res.cost) == pytest.approx(float(jnp.min(res.start_costs)))
    assert float(jnp.max(res.start_costs)) > float(res.cost) + 0.1


def test_rosenbrock_lm():
    res = pem.minimize(_rosen_residual, jnp.array([-1.2, 1.0]), None, max_steps=500)
    np.testing.assert_allclose(res.theta, [1.0, 1.0], atol=1e-6)


def test_minimize_many(linear_problem):
    X, y = linear_problem
    res = pem.minimize_many(_linear_residual, jnp.zeros((2, 3, 3)), (jnp.stack([X, X]),
                                                                       jnp.stack([y, -y])))
    np.testing.assert_allclose(res.theta[0], -res.theta[1], atol=1e-9)
    assert res.covariance.shape == (2, 3, 3)


def _nan_residual(theta, args):
    return (theta * jnp.nan)[None, :]


def test_errors(linear_problem):
    with pytest.raises(FitError, match="finite"):
        pem.minimize(_nan_residual, jnp.zeros(2), None)
    with pytest.raises(ConfigError, match="solver"):
        pem.minimize(_linear_residual, jnp.zeros(3), linear_problem, solver="bfgs")
    with pytest.raises(ConfigError, match="shape"):
        pem.minimize(_linear_residual, jnp.zeros((1, 1, 3)), linear_problem)
