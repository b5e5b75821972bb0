"""`pid_relay`: the firmware's relay auto-tune run on a model. On a first-order-plus-dead-time
plant $K e^{-sL}/(1+sT)$ the relay's ultimate gain and period match the analytic ones,
$\\arctan(\\omega_u T) + \\omega_u L = \\pi$, $K_u = \\sqrt{1+(\\omega_u T)^2}/K$,
$P_u = 2\\pi/\\omega_u$; the asymmetric relay's first harmonic is the closed form; the
Ziegler–Nichols PID settles the loop, never kicks on a set-point step and does not wind up."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

from jthermo.control import FAMILIES, design
from jthermo.control.relay import DiagonalPID, relay_test, ziegler_nichols
from jthermo.errors import ControlError
from jthermo.models import StateSpace
from jthermo.tune.report import CLASSICAL

K, T = 2.0, 10.0          # °C per unit input, s


def fopdt(L: float, ts: float, u0: float = 0.5, y0: float = 50.0) -> StateSpace:
    """$K e^{-sL}/(1+sT)$ sampled with a zero-order hold: a lag state fed by a chain of
    L/ts unit delays."""
    nd = int(round(L / ts))
    a = math.exp(-ts / T)
    n = 1 + nd
    A, B, C = np.zeros((n, n)), np.zeros((n, 1)), np.zeros((1, n))
    A[0, 0], C[0, 0] = a, 1.0
    if nd:
        A[0, n - 1], B[1, 0] = (1 - a) * K, 1.0
        for i in range(2, n):
            A[i, i - 1] = 1.0
    else:
        B[0, 0] = (1 - a) * K
    return StateSpace(A, B, C, ts=ts, u0=np.array([u0]), y0=np.array([y0]))


def ultimate(L: float) -> tuple[float, float]:
    w = brentq(lambda w: math.atan(w * T) + w * L - math.pi, 1e-9, math.pi / L * (1 - 1e-9))
    return math.sqrt(1 + (w * T) ** 2) / K, 2 * math.pi / w


@pytest.mark.parametrize("ratio", [0.1, 0.5, 1.0, 2.0])
def test_relay_finds_the_analytic_ultimate_point(ratio):
    ts = T / 200
    res = relay_test(fopdt(ratio * T, ts))
    ku, pu = ultimate(ratio * T + ts / 2)      # the hold adds half a sample of delay
    assert res.ku == pytest.approx(ku, rel=0.05)
    assert res.pu == pytest.approx(pu, rel=0.05)
    assert res.duty == pytest.approx(0.5, abs=0.01) and res.d_on == res.d_off == 0.5


def test_peak_amplitude_underestimates_a_lag_dominated_plant():
    """The firmware's half peak-to-peak: a near-triangle output overstates its harmonic."""
    m = fopdt(0.1 * T, T / 200)
    peaks, harmonic = relay_test(m, measure="peaks"), relay_test(m)
    assert 0.75 < peaks.ku / harmonic.ku < 0.9          # between 8/pi^2 (triangle) and 1


def test_asymmetric_relay_correction_is_the_first_harmonic():
    """Full power on/off around u* = 0.25: levels +0.75 / -0.25. The closed form
    2 (d1 + d2) sin(pi delta) / pi equals the measured first harmonic of the relay output."""
    m = fopdt(0.5 * T, T / 200, u0=0.25)
    res = relay_test(m, amplitude="full", cycles=4)
    assert (res.d_on, res.d_off) == (0.75, 0.25) and res.duty < 0.45
    n = int(round(4 * res.pu / m.ts))
    u, y = res.u[-n - 1:-1], res.y[-n - 1:-1]
    phase = np.exp(-2j * np.pi * 4 * np.arange(n) / n)
    u1, y1 = 2 * abs(np.mean(u * phase)), 2 * abs(np.mean(y * phase))
    assert res.ku == pytest.approx(u1 / y1, rel=0.02)
    # uncorrected, 4 d / (pi a) with d the mean level, would be off by more
    assert abs(4 * 0.5 / (math.pi * y1) / (u1 / y1) - 1) > 0.05


def test_hysteresis_and_errors():
    m = fopdt(0.5 * T, T / 200)
    plain, band = relay_test(m), relay_test(m, hysteresis=0.05)
    assert band.a > plain.a and band.pu > plain.pu
    with pytest.raises(ControlError, match="no room"):
        relay_test(fopdt(0.5 * T, T / 200, u0=1.0))
    with pytest.raises(ControlError, match="measure"):
        relay_test(m, measure="rms")


def closed_loop(ctrl, model, r, n):
    return (np.asarray(o) for o in traced_loop(ctrl, model, r))


def traced_loop(ctrl, model, r):
    """`(y, u, integral)` of the loop on `model` following `r`, as JAX arrays."""
    A, B, C = (jnp.asarray(x) for x in (model.A, model.B, model.C))
    u0, y0 = jnp.asarray(model.u0), jnp.asarray(model.y0)

    def body(carry, rk):
        x, s = carry
        y = y0 + C @ x
        u, s = ctrl.step(s, y, rk)
        return (A @ x + B @ (u - u0), s), (y, u, s.integral)

    x0 = jnp.zeros(A.shape[0])
    _, out = jax.lax.scan(body, (x0, ctrl.init(y0, r[0])), jnp.asarray(r))
    return out


def test_ziegler_nichols_pid_from_design():
    m = fopdt(0.5 * T, T / 100)
    c = design("pid_relay", m, setpoint=50.4)
    assert isinstance(c, DiagonalPID) and "pid_relay" in FAMILIES and "pid_relay" in CLASSICAL
    res = relay_test(fopdt(0.5 * T, T / 100, u0=0.5 + 0.4 / K, y0=50.4))
    np.testing.assert_allclose([float(c.kp[0]), float(c.ti[0]), float(c.td[0])],
                               ziegler_nichols(res.ku, res.pu), rtol=1e-9)
    assert float(c.u0[0]) == pytest.approx(0.5 + 0.4 / K)
    # a 0.2 °C step: settles at the set point, no derivative kick on the step
    r = np.full((3000, 1), 50.4)
    r[1000:] = 50.6
    y, u, _ = closed_loop(c, design_point_of(m, 50.4), r, 3000)
    assert abs(y[999, 0] - 50.4) < 1e-6 and abs(y[-1, 0] - 50.6) < 0.01
    assert u[1000, 0] - u[999, 0] == pytest.approx(float(c.kp[0]) * (1 + m.ts / float(c.ti[0]))
                                                   * 0.2, rel=1e-6)


def test_pid_does_not_wind_up():
    m = fopdt(0.5 * T, T / 100)
    c = design("pid_relay", m, setpoint=50.0)
    r = np.full((2000, 1), 50.0)
    r[:1000] = 60.0                  # out of reach for 1000 samples (max 51 °C at full power)
    y, u, integ = closed_loop(c, m, r, 2000)
    assert np.all(u[200:1000] == 1.0)
    # integral frozen while saturated: it stays at what it held when saturation began
    assert np.ptp(integ[200:1000]) < 1e-12
    assert abs(y[-1, 0] - 50.0) < 0.05


def design_point_of(model, r):
    from jthermo.control.design import design_point
    return design_point(model, r)


def _pid_before_weight(c, state, y, r):
    """The one-degree-of-freedom law `DiagonalPID.step` had before the set-point weight."""
    e = r - y
    inc = c.kp * (c.ts / c.ti) * e
    tf = c.td / c.n_filter
    deriv = (tf * state.deriv - c.kp * c.td * (y - state.y_prev)) / (tf + c.ts)
    i_try = state.integral + inc
    v = c.u0 + c.kp * e + i_try + deriv
    wind = ((v > c.u_max) & (inc > 0)) | ((v < c.u_min) & (inc < 0))
    return jnp.clip(v, c.u_min, c.u_max), (jnp.where(wind, state.integral, i_try), deriv, y)


def test_setpoint_weight_one_is_the_old_pid_bit_for_bit():
    c = DiagonalPID([0.3, 0.1], [8.0, 20.0], [1.0, 2.5], [0.4, 0.6], ts=0.5)
    assert np.all(np.asarray(c.b) == 1.0)
    rng = np.random.default_rng(3)
    ys = jnp.asarray(50 + 3 * rng.normal(size=(60, 2)))
    rs = jnp.asarray(np.where(np.arange(60)[:, None] < 20, 50.0, [54.0, 47.0]))
    s = c.init(ys[0], rs[0])
    old = (s.integral, s.deriv, s.y_prev)
    for y, r in zip(ys, rs):
        u, s = c.step(s, y, r)
        u_old, old = _pid_before_weight(c, s.__class__(*old, s.y_ref), y, r)
        assert np.array_equal(np.asarray(u), np.asarray(u_old))
        assert all(np.array_equal(np.asarray(a), np.asarray(b))
                   for a, b in zip((s.integral, s.deriv, s.y_prev), old))


def _step_overshoot(c, m, n=600):
    r = np.full((n, 1), 50.0)
    r[100:] = 50.4
    y, u, _ = closed_loop(c, m, r, n)
    return float(y[100:, 0].max() - 50.4), float(abs(y[-1, 0] - 50.4))


def test_setpoint_weight_cuts_the_step_overshoot_and_its_gradient():
    """A first-order plant, $K/(1 + sT)$: the PID's zero makes a set-point step overshoot;
    weighting the set point by b < 1 in the proportional part takes most of it away."""
    m = fopdt(0.0, 0.5)
    pid = DiagonalPID(2.0, 5.0, 0.5, 0.5, ts=0.5)
    over1, err1 = _step_overshoot(pid, m)
    weighted = DiagonalPID(2.0, 5.0, 0.5, 0.5, ts=0.5, b=0.3)
    np.testing.assert_allclose(weighted.b, 0.3, rtol=1e-12)
    over_b, err_b = _step_overshoot(weighted, m)
    assert over1 > 0.01 and over_b < 0.5 * over1 and err1 < 1e-6 and err_b < 1e-6
    r = np.full((400, 1), 50.0)
    r[50:] = 50.4

    def cost(angle):
        y = traced_loop(eqx.tree_at(lambda k: k.b_angle, weighted, angle), m, r)[0]
        return jnp.mean((y - jnp.asarray(r)) ** 2)

    theta, h = jnp.asarray([0.7]), 1e-6
    g = float(jax.grad(cost)(theta)[0])
    fd = (float(cost(theta + h)) - float(cost(theta - h))) / (2 * h)
    assert g == pytest.approx(fd, rel=1e-5) and abs(g) > 1e-8


def test_setpoint_weight_outside_zero_one_is_refused():
    for b in (-0.1, 1.5, float("nan")):
        with pytest.raises(ControlError, match="set-point weight"):
            DiagonalPID(0.1, 10.0, 1.0, b=b)
