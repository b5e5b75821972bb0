"""`Polynomial.simulate` from a state `x0` of its parallel realisation (input denominators):
the response from rest plus each block's free response, equal to the dense realisation's
simulation, with the same Jacobian in `x0` (what `compare` uses to estimate the initial state)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.data import from_arrays
from jthermo.errors import ModelError
from jthermo.models.polynomial import Polynomial
from jthermo.validate import estimate_initial_state

NY, NU, T = 3, 2, 60


def _model(kind: str, seed: int = 0) -> Polynomial:
    rng = np.random.default_rng(seed)
    b = 0.1 * rng.random((NY, NU, 2))
    kw = {"oe": {"f": -0.9 + 0.05 * rng.random((NY, NU, 1))},
          "bj": {"f": np.stack([-1.5 + 0.05 * rng.random((NY, NU)), 0.6 * np.ones((NY, NU))], -1),
                 "c": 0.2 * np.ones((NY, 2)), "d": -0.3 * np.ones((NY, 1))},
          "armax_f": {"a": -0.5 * np.ones((NY, 1)), "f": -0.8 * np.ones((NY, NU, 1)),
                      "c": 0.3 * np.ones((NY, 1))}}[kind]
    return Polynomial(b=b, nk=1, u0=0.1 * np.ones(NU), y0=np.ones(NY), **kw)


@pytest.mark.parametrize("kind", ["oe", "bj", "armax_f"])
def test_simulate_from_state_matches_the_realisation(kind):
    m = _model(kind)
    ss = m.to_statespace()
    rng = np.random.default_rng(1)
    x0, u = jnp.asarray(rng.standard_normal(ss.A.shape[0])), jnp.asarray(rng.random((T, NU)))
    np.testing.assert_allclose(m.simulate(u, x0=x0), ss.simulate(u, x0=x0), rtol=1e-12, atol=1e-12)
    # the Jacobian in x0 (the observability matrix compare's least squares uses)
    J = jax.jacfwd(lambda x: m.simulate(u, x0=x))(x0)
    J_ref = jax.jacfwd(lambda x: ss.simulate(u, x0=x))(x0)
    np.testing.assert_allclose(J, J_ref, rtol=1e-12, atol=1e-12)
    # and a central difference along one direction
    v, h = jnp.asarray(rng.standard_normal(x0.shape)), 1e-6
    fd = (m.simulate(u, x0=x0 + h * v) - m.simulate(u, x0=x0 - h * v)) / (2 * h)
    np.testing.assert_allclose(fd, jnp.einsum("tis,s->ti", J, v), rtol=1e-6, atol=1e-8)


def test_initial_state_is_recovered():
    m = _model("oe")
    nx = m.to_statespace().A.shape[0]
    rng = np.random.default_rng(2)
    x0, u = rng.standard_normal(nx), rng.random((200, NU))
    y = np.asarray(m.to_statespace().simulate(jnp.asarray(u), x0=jnp.asarray(x0)))
    x_hat = estimate_initial_state(m, from_arrays(u, y))
    np.testing.assert_allclose(m.simulate(u, x0=x_hat), y, atol=1e-8)


def test_wrong_state_shape_is_a_model_error():
    m = _model("oe")
    with pytest.raises(ModelError, match="x0 must have shape"):
        m.simulate(np.zeros((T, NU)), x0=jnp.zeros(3))
