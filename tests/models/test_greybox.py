import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import signal

from jthermo.data import from_arrays
from jthermo.errors import ModelError
from jthermo.identify.greybox import fit_greybox
from jthermo.models.greybox import BedModel, ExtendedBedModel, zoh


def _truth(n=3):
    cap = np.array([900.0, 1100.0, 1000.0])[:n]
    loss = np.array([5.0, 4.0, 6.0])[:n]
    gain = 60.0 * np.eye(n) + 15.0 * (1 - np.eye(n))
    return cap, loss, gain


def _prbs(T, n, seed):
    rng = np.random.default_rng(seed)
    hold = 20
    levels = rng.integers(0, 2, size=(T // hold + 1, n)) * 0.6 + 0.2
    return np.repeat(levels, hold, axis=0)[:T]


def test_zoh_matches_scipy():
    cap, loss, gain = _truth()
    m = BedModel.from_physical(cap, loss, gain, ts=1.0)
    A, B, Bw = m.continuous()
    Ad, Bd, *_ = signal.cont2discrete((np.asarray(A), np.asarray(jnp.concatenate([B, Bw], 1)),
                                       np.eye(3), np.zeros((3, 4))), 1.0, method="zoh")
    ss = m.to_statespace()
    np.testing.assert_allclose(ss.A, Ad, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(jnp.concatenate([ss.B, ss.Bw], 1), Bd, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.diag(ss.A), np.exp(-loss / cap), rtol=1e-12)
    assert m.n_signals == 1 and m.n_inputs == 3 and m.n_outputs == 3
    # steady state: T - Ts = n u / G
    np.testing.assert_allclose(ss.dcgain(), gain / loss[:, None], rtol=1e-9)


def test_positive_parameters_and_errors():
    cap, loss, gain = _truth()
    with pytest.raises(ModelError, match="must be finite and > 0"):
        BedModel.from_physical(cap, -loss, gain)
    with pytest.raises(ModelError, match="`gain` has shape"):
        BedModel.from_physical(cap, loss, gain[:2])


def test_zoh_gradient_matches_finite_difference():
    cap, loss, gain = _truth()
    m = BedModel.from_physical(cap, loss, gain)

    def f(ll):
        A = -jnp.diag(jnp.exp(ll) / jnp.asarray(cap))
        Ad, _ = zoh(A, jnp.asarray(gain) / jnp.asarray(cap)[:, None], 1.0)
        return jnp.sum(Ad**2)

    g = jax.grad(f)(m.log_loss)
    eps = 1e-6
    fd = np.array([(f(m.log_loss.at[i].add(eps)) - f(m.log_loss.at[i].add(-eps))) / (2 * eps)
                   for i in range(3)])
    np.testing.assert_allclose(g, fd, rtol=1e-6)


def test_constant_surroundings_equals_measured():
    cap, loss, gain = _truth()
    u = _prbs(200, 3, 0)
    a = BedModel.from_physical(cap, loss, gain)
    b = BedModel.from_physical(cap, loss, gain, surroundings=25.0, measured_surroundings=False)
    ya = a.simulate(u, np.full((200, 1), 25.0), x0=jnp.full(3, 30.0))
    yb = b.simulate(u, x0=jnp.full(3, 5.0))
    np.testing.assert_allclose(ya, yb, atol=1e-9)


def test_extended_reduces_to_bed():
    cap, loss, gain = _truth()
    ext = ExtendedBedModel.from_physical(np.r_[cap, 5000.0], np.r_[loss, 2.0],
                                         np.vstack([gain, np.zeros(3)]),
                                         coupling=[1e-300], edges=[(0, 3)])
    bed = BedModel.from_physical(cap, loss, gain)
    u = _prbs(100, 3, 1)
    w = np.full((100, 1), 20.0)
    y1 = ext.simulate(u, w, x0=jnp.r_[jnp.full(3, 20.0), 20.0])
    y2 = bed.simulate(u, w, x0=jnp.full(3, 20.0))
    np.testing.assert_allclose(y1, y2, atol=1e-9)
    # a wall coupled to zone 0 slows it: the extra node is a state
    ext2 = ExtendedBedModel.from_physical(np.r_[cap, 5000.0], np.r_[loss, 2.0],
                                          np.vstack([gain, np.zeros(3)]), coupling=[3.0],
                                          edges=[(0, 3)])
    assert ext2.n_states == 4 and ext2.n_outputs == 3
    A, _, _ = ext2.continuous()
    np.testing.assert_allclose(np.asarray(A).sum(1) + np.asarray(ext2.continuous()[2])[:, 0], 0, atol=1e-12)


@pytest.mark.parametrize("measured", [True, False])
def test_fit_recovers_parameters(measured):
    cap, loss, gain = _truth()
    T = 1500
    u = _prbs(T, 3, 2)
    w = 22.0 + 0.0 * np.arange(T)[:, None] if not measured else 22.0 + 3 * np.sin(np.arange(T) / 300)[:, None]
    true = BedModel.from_physical(np.full(3, 1000.0), loss * 1000 / cap, gain * 1000 / cap[:, None])
    y = np.asarray(true.simulate(u, w, x0=jnp.full(3, 40.0)))
    y = y + 0.05 * np.random.default_rng(3).normal(size=y.shape)
    data = from_arrays(u, y, 1.0, w if measured else None)
    fit = fit_greybox(data)
    model = fit.model
    np.testing.assert_allclose(np.exp(model.log_loss), loss * 1000 / cap, rtol=0.05)
    np.testing.assert_allclose(np.exp(model.log_gain), gain * 1000 / cap[:, None], rtol=0.05)
    if not measured:
        assert abs(float(model.surroundings) - 22.0) < 0.5
    # the design point is the estimation data's mean input (and measured surroundings)
    u_nom, w_nom = model.nominal_point()
    np.testing.assert_allclose(np.asarray(u_nom), u.mean(axis=0), rtol=1e-12)
    if measured:
        np.testing.assert_allclose(np.asarray(w_nom), [w.mean()], rtol=1e-12)
    else:
        assert w_nom is None
