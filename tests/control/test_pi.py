"""Diagonal PI: discretisation, saturation and anti-windup."""

import equinox as eqx
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


def _pi_before_weight(pi, state, y, r):
    """The one-degree-of-freedom law `DiagonalPI.step` had before the set-point weight."""
    e = r - y
    ki = pi.kp * pi.ts / pi.ti
    inc = 0.5 * ki * (e + state.error) if pi.method == "tustin" else ki * e
    i_try = state.integral + inc
    v = pi.u0 + pi.kp * e + i_try
    u = jnp.clip(v, pi.u_min, pi.u_max)
    if pi.antiwindup == "clamp":
        wind = ((v > pi.u_max) & (inc > 0)) | ((v < pi.u_min) & (inc < 0))
        return u, jnp.where(wind, state.integral, i_try)
    if pi.antiwindup == "backcalc":
        return u, i_try + (pi.ts / jnp.sqrt(pi.ti * pi.ts)) * (u - v)
    return u, i_try


@pytest.mark.parametrize("kw", [{}, {"method": "tustin", "antiwindup": "backcalc"},
                                {"antiwindup": "none"}])
def test_setpoint_weight_one_is_the_old_pi_bit_for_bit(kw):
    pi = DiagonalPI(jnp.array([0.3, 0.1]), jnp.array([8.0, 20.0]), 0.5, ts=0.5, **kw)
    assert np.all(np.asarray(pi.b) == 1.0)
    rng = np.random.default_rng(4)
    ys = jnp.asarray(50 + 3 * rng.normal(size=(60, 2)))
    rs = jnp.asarray(np.where(np.arange(60)[:, None] < 20, 50.0, [54.0, 47.0]))
    s = pi.init(ys[0], rs[0])
    for y, r in zip(ys, rs):
        u_old, i_old = _pi_before_weight(pi, s, y, r)
        u, s = pi.step(s, y, r)
        assert np.array_equal(np.asarray(u), np.asarray(u_old))
        assert np.array_equal(np.asarray(s.integral), np.asarray(i_old))


def _first_order_step(pi, n=300, a=0.95, gain=2.0):
    """$y_{k+1} = a y_k + (1 - a) K (u_k - 0.5)$ around 50 °C; the set point steps 50 -> 50.4."""
    r = jnp.where(jnp.arange(n) < 20, 50.0, 50.4)[:, None]

    def body(carry, rk):
        y, s = carry
        u, s = pi.step(s, y, rk)
        return (50.0 + a * (y - 50.0) + (1 - a) * gain * (u - 0.5), s), y[0]

    y0 = jnp.array([50.0])
    return jax.lax.scan(body, (y0, pi.init(y0, r[0])), r)[1], r[:, 0]


def test_setpoint_weight_cuts_the_overshoot_and_its_gradient():
    over = {}
    for b in (1.0, 0.3):
        y, r = _first_order_step(DiagonalPI(2.0, 5.0, 0.5, ts=0.5, b=b))
        over[b] = float(y.max() - 50.4)
        assert abs(float(y[-1]) - 50.4) < 1e-6
    assert over[1.0] > 0.002 and over[0.3] < 0.1 * over[1.0]

    def cost(angle):
        pi = eqx.tree_at(lambda c: c.b_angle, DiagonalPI(2.0, 5.0, 0.5, ts=0.5, b=0.3), angle)
        y, r = _first_order_step(pi, 120)
        return jnp.mean((y - r) ** 2)

    theta, h = jnp.asarray([0.7]), 1e-6
    g = float(jax.grad(cost)(theta)[0])
    fd = (float(cost(theta + h)) - float(cost(theta - h))) / (2 * h)
    assert g == pytest.approx(fd, rel=1e-5) and abs(g) > 1e-8
    with pytest.raises(ControlError, match="set-point weight"):
        DiagonalPI(0.1, 30.0, b=1.2)
