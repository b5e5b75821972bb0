"""The host-side simulation and least-squares initial state of linear models
(`models.statespace_numpy`) equal the JAX path of `validate.compare` they replace."""

import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.data import from_arrays
from jthermo.models import polynomial
from jthermo.models import StateSpace
from jthermo.models.greybox import BedModel
from jthermo.models import statespace_numpy as ssn
from jthermo.validate import compare, estimate_initial_state


def _bed(measured):
    rng = np.random.default_rng(5)
    n, T = 3, 400
    model = BedModel.from_physical(np.full(n, 1000.0), rng.uniform(4, 8, n),
                                   50 * np.eye(n) + 5.0, measured_surroundings=measured,
                                   surroundings=22.0)
    u = rng.uniform(0, 1, (T, n))
    w = 22.0 + np.sin(np.arange(T) / 50.0)[:, None] if measured else None
    y = np.asarray(model.simulate(u, w, x0=jnp.full(n, 7.0 if not measured else 30.0)))
    y = y + 0.05 * rng.standard_normal(y.shape)
    return model, from_arrays(u, y, 1.0, w)


@pytest.mark.parametrize("measured", [True, False])
def test_initial_state_and_simulation_equal_the_jax_path(measured):
    model, data = _bed(measured)
    assert ssn.supported(model)
    m = ssn.arrays(model)
    x0 = np.array([1.0, -2.0, 0.5])
    ref = np.asarray(model.simulate(jnp.asarray(data.u), None if data.w.shape[1] == 0
                                    else jnp.asarray(data.w), jnp.asarray(x0)))
    np.testing.assert_allclose(ssn.simulate(m, data.u, data.w, x0), ref, rtol=0, atol=1e-10)
    fast = compare(model, data)                       # the host path
    slow = compare(model, data, x0=np.asarray(fast["x0"]))    # the JAX path from that state
    np.testing.assert_allclose(fast["x0"], np.asarray(estimate_initial_state(model, data)),
                               rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(fast["yhat"], slow["yhat"], atol=1e-9)
    # the least-squares state: no other state simulates the data better
    for dx in (np.eye(3) * 1e-3):
        worse = compare(model, data, x0=np.asarray(fast["x0"]) + dx)
        assert worse["mean_fit_percent"] <= fast["mean_fit_percent"] + 1e-9


def test_statespace_with_feedthrough_and_offsets():
    rng = np.random.default_rng(6)
    ss = StateSpace(np.array([[0.9, 0.1], [0.0, 0.8]]), rng.standard_normal((2, 2)),
                    rng.standard_normal((2, 2)), D=0.1 * rng.standard_normal((2, 2)),
                    u0=[0.5, 0.5], y0=[20.0, 21.0])
    u = rng.uniform(0, 1, (200, 2))
    np.testing.assert_allclose(ssn.simulate(ssn.arrays(ss), u, None, np.array([1.0, 2.0])),
                               np.asarray(ss.simulate(u, None, jnp.array([1.0, 2.0]))), atol=1e-10)


def test_polynomial_models_keep_their_own_path():
    assert not ssn.supported(polynomial.ARX(np.array([[-0.9]]), np.array([[[0.1]]]), nk=1))
