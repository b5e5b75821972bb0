import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.control import DecoupledPI, design, design_feedforward, design_imc, design_lqg, gated
from jthermo.control.pi import DiagonalPI
from jthermo.errors import ControlError

from .loop import bed_plant, closed_loop, step_reference

T = 200


@pytest.fixture(scope="module")
def plant():
    return bed_plant(3)


@pytest.mark.parametrize("family", ["pi_lambda", "pi_decoupled", "feedforward", "imc", "lqg",
                                    "gated_pi"])
def test_tracks_a_step_without_offset(plant, family):
    c = design(family, plant)
    r = step_reference(plant, T, 1.0)
    ys, us = jax.jit(closed_loop)(c, plant, r)
    assert np.all(np.isfinite(ys))
    assert np.max(np.abs(ys[-1] - r[-1])) < 0.02
    assert np.all((us >= 0) & (us <= 1))


def test_imc_on_perfect_model_is_the_filter(plant):
    lam = 5.0
    c = design_imc(plant, filter_tc=lam)
    assert c.inverse
    r = step_reference(plant, 60, 0.5)
    ys, _ = closed_loop(c, plant, r)
    a = np.exp(-1.0 / lam)
    k = np.arange(60)
    want = np.asarray(plant.y0)[None] + 0.5 * (1 - a ** np.clip(k, 0, None))[:, None]
    # y = F_lambda r: a first-order filter with one sample delay (z_{k+1} is reached at k+1)
    np.testing.assert_allclose(ys, want, atol=1e-9)


def test_ideal_feedforward_on_perfect_model(plant):
    Tref = 8.0
    c = design_feedforward(plant, kind="ideal", T=Tref)
    assert c.inverse
    r = step_reference(plant, 60, 0.5)
    ys, _ = closed_loop(c, plant, r)
    a = np.exp(-1.0 / Tref)
    want = np.asarray(plant.y0)[None] + 0.5 * (1 - a ** np.arange(60))[:, None]
    np.testing.assert_allclose(ys, want, atol=1e-9)


def test_neutral_feedforward_on_perfect_model(plant):
    c = design_feedforward(plant, kind="neutral")
    r = step_reference(plant, 150, 0.5)
    ys, _ = closed_loop(c, plant, r)
    # y equals the reference model G G(0)^-1 r: the feedback PI has nothing to do
    dr = np.full(3, 0.5)
    du = np.linalg.solve(np.asarray(plant.dcgain()), dr)
    want = plant.simulate(np.broadcast_to(np.asarray(plant.u0) + du, (150, 3)),
                          x0=plant.initial_state(plant.y0))
    np.testing.assert_allclose(ys, want, atol=1e-9)
    assert np.max(np.abs(ys[-1] - r[-1])) < 1e-3


@pytest.mark.parametrize("family", ["pi_lambda", "pi_decoupled", "feedforward", "lqg"])
def test_anti_windup_under_constant_disturbance(plant, family):
    """A constant cold load drives the input to 1 for 150 s; after it stops the loop must
    come back without a windup overshoot."""
    c = design(family, plant)
    n = 350
    r = step_reference(plant, n, 0.0)
    d = np.zeros((n, 3))
    d[50:200] = -0.6                      # °C per sample: far more than the heaters can give
    ys, us = closed_loop(c, plant, r, jnp.asarray(d))
    assert np.all(us[120:200] > 1 - 1e-9)   # saturated while the load acts
    after = np.asarray(ys[200:] - r[200:])
    # without anti-windup the integrators grow for 150 s and the bed overshoots by degrees
    assert after.max() < 0.6
    assert np.max(np.abs(after[-30:])) < 0.05


def test_windup_would_overshoot(plant):
    """The check above has teeth: the same PI without anti-windup overshoots."""
    c = design("pi_lambda", plant)
    n = 350
    r = step_reference(plant, n, 0.0)
    d = np.zeros((n, 3))
    d[50:200] = -0.6

    naive = DiagonalPI(c.kp, c.ti, c.u0, ts=1.0, antiwindup="none")
    ys, _ = closed_loop(naive, plant, r, jnp.asarray(d))
    assert np.max(ys[200:] - r[200:]) > 1.0


def test_gated_switches(plant):
    inner = design("pi_lambda", plant)
    g = gated(inner, band=2.0, u_below=0.9, u_above=0.05)
    y0 = plant.y0
    s = g.init(y0, y0)
    u_far_below, _ = g.step(s, y0 - 10.0, y0)
    u_far_above, _ = g.step(s, y0 + 10.0, y0)
    u_in, _ = g.step(s, y0 + 0.1, y0)
    u_inner, _ = inner.step(inner.init(y0, y0), y0 + 0.1, y0)
    np.testing.assert_allclose(u_far_below, 0.9, atol=1e-6)
    np.testing.assert_allclose(u_far_above, 0.05, atol=1e-6)
    np.testing.assert_allclose(u_in, u_inner, atol=1e-4)
    with pytest.raises(ControlError, match="band must be positive"):
        gated(inner, band=-1.0)


def test_lqg_errors(plant):
    with pytest.raises(ControlError, match="Q2 must be positive"):
        design_lqg(plant, Q2=-1.0)


def test_shape_errors():
    with pytest.raises(ControlError, match="W1 has shape"):
        DecoupledPI(jnp.ones(2), jnp.ones(2), 0.5, jnp.eye(3))
