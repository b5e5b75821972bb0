"""Diagonal PI: discretisation, saturation and anti-windup."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.control.pi import DiagonalPI
from jthermo.errors import ControlError


def _run(pi, ys, r):
    state = pi.init(ys[0], r)
    out = []
    for y in ys:
        u, state = pi.step(state, y, r)
        out.append(u)
    return jnp.stack(out)


def test_backward_euler_and_tustin_laws():
    pi = DiagonalPI(jnp.array([0.02, 0.03]), jnp.array([50.0, 80.0]), 0.5, ts=2.0)
    rng = np.random.default_rng(0)
    ys = jnp.asarray(170 + rng.normal(size=(30, 2)))
    r = jnp.array([170.0, 170.5])
    u = _run(pi, ys, r)
    e = np.asarray(r - ys)
    ref = 0.5 + np.asarray(pi.kp) * (e + 2.0 / np.asarray(pi.ti) * np.cumsum(e, axis=0))
    np.testing.assert_allclose(u, ref, rtol=1e-12)
    tu = DiagonalPI(pi.kp, pi.ti, 0.5, ts=2.0, method="tustin")
    u2 = _run(tu, ys, r)
    e_prev = np.vstack([e[:1], e[:-1]])        # init() stores the first error
    ref2 = 0.5 + np.asarray(pi.kp) * (e + 1.0 / np.asarray(pi.ti) * np.cumsum(e + e_prev, axis=0))
    np.testing.assert_allclose(u2, ref2, rtol=1e-12)


@pytest.mark.parametrize("mode", ["clamp", "backcalc"])
def test_antiwindup_under_a_saturating_constant_disturbance(mode):
    """A first-order zone with a constant heat sink that the heater cannot beat: the input sits
    at 1 for a long time; when the sink goes, anti-windup lets the input leave the limit at
    once, while the plain PI stays saturated and overshoots."""
    a, b = 0.95, 2.0          # T+ = a T + b u - sink, in °C above the surroundings

    def loop(pi, T=600):
        x, state = jnp.array([30.0]), pi.init(jnp.array([30.0]), jnp.array([30.0]))
        xs, us = [], []
        for k in range(T):
            sink = 3.0 if k < 300 else 0.0
            u, state = pi.step(state, x, jnp.array([30.0]))
            u = jnp.clip(u, 0.0, 1.0)
            x = a * x + b * u - sink
            xs.append(float(x[0]))
            us.append(float(u[0]))
        return np.array(xs), np.array(us)

    kw = dict(kp=jnp.array([0.05]), ti=jnp.array([20.0]), u0=0.5)
    xs_aw, us_aw = loop(DiagonalPI(**kw, antiwindup=mode))
    xs_no, us_no = loop(DiagonalPI(**kw, antiwindup="none"))
    assert np.all(us_aw[250:300] == 1.0) and np.all(us_no[250:300] == 1.0)   # saturated
    assert np.all(us_aw <= 1.0) and np.all(us_aw >= 0.0)
    def leave(us):   # samples until the input comes off the limit after the sink goes
        off = np.flatnonzero(us[300:] < 1.0)
        return off[0] if off.size else len(us) - 300

    assert 2 * leave(us_aw) < leave(us_no)
    assert xs_aw[300:].max() - 30.0 < 0.3 * (xs_no[300:].max() - 30.0)


def test_untuned_and_gradients_and_errors():
    pi = DiagonalPI.untuned(3)
    assert pi.zones == 3 and np.allclose(pi.kp, pi.kp[0]) and np.allclose(pi.ti, pi.ti[0])
    ys = jnp.full((5, 3), 171.0)

    def f(kp):
        return jnp.sum(_run(DiagonalPI(kp, pi.ti), ys, jnp.full(3, 172.0)))

    g = jax.grad(f)(jnp.full(3, 0.1))
    np.testing.assert_allclose(g, 5 * 1.0 + 1.0 / 30.0 * 15, rtol=1e-12)
    with pytest.raises(ControlError, match="antiwindup"):
        DiagonalPI(0.1, 30.0, antiwindup="off")
    with pytest.raises(ControlError, match="method"):
        DiagonalPI(0.1, 30.0, method="zoh")
    with pytest.raises(ControlError, match="zones must be"):
        DiagonalPI.untuned(0)
    with pytest.raises(ControlError, match="one length"):
        DiagonalPI(jnp.ones(2), jnp.ones(3))
