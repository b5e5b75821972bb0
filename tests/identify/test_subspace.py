"""N4SID: exact recovery on noise-free data, simulation against scipy, order choice, errors."""

import numpy as np
import pytest
import scipy.signal

from jthermo.data import from_arrays
from jthermo.errors import DataError, ModelError
from jthermo.identify.subspace import choose_order, n4sid, n4sid_variants, project_stable
from jthermo.models import is_stable


def _system(seed=0, nx=3, nu=2, ny=2):
    """A stable MIMO system with known real and complex poles."""
    rng = np.random.default_rng(seed)
    poles = np.array([0.9, 0.7 + 0.2j, 0.7 - 0.2j, 0.5, 0.3][:nx])
    if np.iscomplexobj(poles) and nx == 3:
        Lam = np.array([[0.9, 0, 0], [0, 0.7, 0.2], [0, -0.2, 0.7]])
    else:
        Lam = np.diag(np.real(poles))
    V = rng.standard_normal((nx, nx)) + 2 * np.eye(nx)
    A = V @ Lam @ np.linalg.inv(V)
    B = rng.standard_normal((nx, nu))
    C = rng.standard_normal((ny, nx))
    return A, B, C, np.sort_complex(np.linalg.eigvals(Lam))


def _noise_free(T=1000, seed=0, nx=3):
    """Noise-free data of order `nx` in periodic steady state with a zero-mean input per period,
    so that the sample means are exactly the operating point (otherwise the mean offset adds a
    state)."""
    A, B, C, poles = _system(seed, nx=nx)
    rng = np.random.default_rng(seed + 10)
    period = rng.standard_normal((T // 2, B.shape[1]))
    period -= period.mean(0)
    du = np.concatenate([period] * 6)
    x = np.zeros(A.shape[0])
    y = np.empty((len(du), C.shape[0]))
    for k in range(len(du)):
        y[k] = 20.0 + C @ x
        x = A @ x + B @ du[k]
    return from_arrays(0.5 + du[-T:], y[-T:]), (A, B, C, poles)


def test_noise_free_poles_recovered():
    data, (_, _, _, poles) = _noise_free()
    for weighting in ("cva", "moesp", "n4sid"):
        model, svals = n4sid(data, 3, weighting=weighting)
        est = np.sort_complex(np.linalg.eigvals(np.asarray(model.A)))
        np.testing.assert_allclose(est, poles, atol=1e-7)
        assert svals[3] < 1e-8 * svals[0]


def test_noise_free_order_and_simulation():
    data, _ = _noise_free()
    model, svals = n4sid(data)            # order from the singular values
    assert model.A.shape == (3, 3)
    assert choose_order(svals) == 3
    # the estimate reproduces the data (same input/output map, any basis) once the unknown
    # initial state has decayed (slowest pole 0.9: 0.9**300 ~ 2e-14)
    y_sim = np.asarray(model.simulate(data.u))
    assert np.max(np.abs(y_sim - data.y)[300:]) < 1e-6 * np.ptp(data.y)


def test_simulate_matches_dlsim():
    data, _ = _noise_free(T=400)
    model, _ = n4sid(data, 3, feedthrough=True)
    A, B, C, D = (np.asarray(m) for m in (model.A, model.B, model.C, model.D))
    du = data.u - np.asarray(model.u0)
    x0 = np.array([0.1, -0.2, 0.3])
    _, y_ref, _ = scipy.signal.dlsim((A, B, C, D, 1.0), du, x0=x0)
    y = np.asarray(model.simulate(data.u, x0=x0))
    np.testing.assert_allclose(y, y_ref + np.asarray(model.y0), rtol=1e-10, atol=1e-10)


def test_variants_share_order_and_are_stable():
    data, _ = _noise_free()
    out = n4sid_variants(data, 3, horizon=8)
    assert len(out) == 2
    for model, _ in out:
        assert is_stable(model)
        assert np.asarray(model.K).shape == (3, 2)


def test_choose_order_gap():
    assert choose_order([10.0, 9.0, 8.0, 0.1, 0.09]) == 3
    assert choose_order([1.0, 1e-15, 1e-16]) == 1
    with pytest.raises(ModelError, match="at least two"):
        choose_order([1.0])


def test_choose_order_finds_the_data_order_below_max_order():
    # noise-free data of a second-order system: the Hankel singular values vanish after two
    data, (_, _, _, poles) = _noise_free(nx=2)
    assert len(poles) == 2
    _, svals = n4sid(data, None, horizon=6)
    assert svals[1] > 1e-3 * svals[0] and svals[2] < 1e-8 * svals[0]
    assert choose_order(svals, max_order=4) == 2   # a cap above the order: the order itself
    assert choose_order(svals, max_order=1) == 1   # a cap below the order binds


def test_project_stable():
    A = np.array([[1.2, 0.3], [0.0, 0.5]])
    P = project_stable(A, 0.99)
    lam = np.sort(np.abs(np.linalg.eigvals(P)))
    np.testing.assert_allclose(lam, [0.5, 0.99], atol=1e-12)
    Ain = np.array([[0.5, 0.1], [0.0, 0.2]])
    np.testing.assert_array_equal(project_stable(Ain), Ain)


def test_errors():
    data, _ = _noise_free(T=200)
    with pytest.raises(ModelError, match="weighting"):
        n4sid(data, 2, weighting="bogus")
    with pytest.raises(ModelError, match="positive integer"):
        n4sid(data, 0)
    with pytest.raises(DataError, match="too few"):
        n4sid(data, 2, horizon=30)
    const = data.replace(u=np.ones_like(data.u))
    with pytest.raises(DataError, match="constant"):
        n4sid(const, 2)


def test_rest_operating_point_exact_on_cold_start():
    """A record that starts at rest (x = 0, zero input) with a non-zero-mean input: the 'rest'
    operating point is exact, where the sample means would add an offset state."""
    A, B, C, poles = _system(1)
    rng = np.random.default_rng(5)
    u = 0.5 + rng.standard_normal((800, 2))
    x = np.zeros(3)
    y = np.empty((800, 2))
    for k in range(800):
        y[k] = 20.0 + C @ x
        x = A @ x + B @ u[k]
    data = from_arrays(u, y)
    model, _ = n4sid(data, 3, operating_point="rest")
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(np.asarray(model.A))), poles,
                               atol=1e-7)
    np.testing.assert_allclose(np.asarray(model.y0), y[0])
    np.testing.assert_allclose(np.asarray(model.simulate(u)), y, atol=1e-6)
    with pytest.raises(ModelError, match="operating_point"):
        n4sid(data, 3, operating_point="bogus")
