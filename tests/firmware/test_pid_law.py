"""Klipper's PID law: jthermo's `KlipperPID` in jthermo's closed loop against an independent
re-implementation of `heaters.py` (tests/firmware/reference.py) running the gains read back from
the exported `printer.cfg` lines, on a simple hot-end plant; and `PID_CALIBRATE` on a model."""

import re

import jax
import numpy as np
import pytest

from jthermo.closedloop import model_scenario, simulate
from jthermo.firmware import settings
from jthermo.firmware.pid import KlipperPID, from_standard, pid_calibrate
from jthermo.models import StateSpace

from . import reference as ref

jax.config.update("jax_enable_x64", True)


def hotend(ts=1.0, n=1):
    """Block + sensor as two first-order lags: heater block (time constant 120 s, 250 °C per
    full duty) and sensor (5 s), exact ZOH at `ts`; n independent heaters."""
    a1, a2 = np.exp(-ts / 120.0), np.exp(-ts / 5.0)
    A1 = np.array([[a1, 0.0], [1 - a2, a2]])
    B1 = np.array([250.0 * (1 - a1), 0.0])
    A = np.kron(np.eye(n), A1)
    B = np.kron(np.eye(n), B1[:, None])
    C = np.kron(np.eye(n), np.array([[0.0, 1.0]]))
    return StateSpace(A, B, C, ts=ts, u0=np.full(n, 0.7), y0=np.full(n, 25.0 + 0.7 * 250.0))


def read_cfg(text, heater):
    body = text.split(f"[{heater}]")[1].split("\n[")[0]
    return {k: float(v) for k, v in re.findall(r"^(pid_K[pid]|max_power|smooth_time): ([-\d.]+)$",
                                                body, re.MULTILINE)}


@pytest.mark.parametrize("n, smooth, max_power", [(1, 1.0, 1.0), (1, 2.5, 0.8), (16, 1.0, 1.0),
                                                   (16, "each", 1.0)])
def test_exported_gains_match_jthermo_loop(n, smooth, max_power):
    """`smooth="each"`: one derivative smoothing per heater (0.5 to 20 s), as the tuning sets."""
    plant = hotend(n=n)
    rng = np.random.default_rng(n)
    kp, ki, kd = (rng.uniform(lo, hi, n) for lo, hi in ((10, 40), (0.5, 2.0), (40, 150)))
    if smooth == "each":
        smooth = np.round(rng.uniform(0.5, 20.0, n), 3)
    ctrl = KlipperPID(kp, ki, kd, ts=1.0, max_power=max_power, smooth_time=smooth,
                      u_hold=np.full(n, 0.6)).rounded()
    names = ["extruder"] + [f"extruder{i}" for i in range(1, n)]
    text = settings.klipper_cfg(ctrl, names)
    sc = model_scenario("tracking", plant, 300.0, jax.random.key(3), setpoint=25 + 0.6 * 250)
    traj = simulate(plant, ctrl, sc)
    A, B, C = (np.asarray(m) for m in (plant.A, plant.B, plant.C))
    u0, y0 = np.asarray(plant.u0), np.asarray(plant.y0)
    r, v, dy = (np.asarray(a) for a in (sc.r, sc.v, sc.d.dy))
    for i, h in enumerate(names):
        g = read_cfg(text, h)
        tau = float(np.broadcast_to(smooth, (n,))[i])
        assert g["max_power"] == max_power and g["smooth_time"] == tau
        heater = ref.KlipperHeater(g["pid_Kp"], g["pid_Ki"], g["pid_Kd"], max_power, tau)
        s = slice(2 * i, 2 * i + 2)
        x0 = np.linalg.solve(np.eye(2) - A[s, s], B[s, i] * (0.6 - u0[i]))
        ys, us = ref.closed_loop(A[s, s], B[s, i], C[i, s], u0[i], y0[i], heater, r[:, i], x0,
                                 1.0, noise=v[:, i] + dy[:, i], duty0=0.6)
        np.testing.assert_allclose(np.asarray(traj.y)[:, i], ys, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.asarray(traj.u)[:, i], us, rtol=0, atol=1e-9)
        assert np.ptp(us) > 0.05          # the loop moved: the set-point changes were followed


def test_law_pieces_by_hand():
    """Integral clamp, anti-windup, derivative smoothing and the update suppression on a
    hand-worked sequence."""
    c = KlipperPID(25.5, 2.55, 51.0, ts=0.5, smooth_time=1.0, max_power=0.5)
    s = c.init(np.array([100.0]), np.array([200.0]))      # cold start: integral 0, duty 0
    u, s = c.step(s, np.array([100.0]), np.array([200.0]))
    # e = 100, I = min(50, max_power / Ki = 50) = 50 -> co = (25.5*100 + 2.55*50)/255 > 0.5
    assert float(u[0]) == 0.5 and float(s.integ[0]) == 0.0            # saturated: I not kept
    u, s = c.step(s, np.array([101.0]), np.array([200.0]))
    # dT/dt smoothed: (0 * (1 - 0.5) + 1.0) / 1.0 = 1.0 °C/s
    assert float(s.deriv[0]) == pytest.approx(1.0)
    c2 = KlipperPID(2.55, 0.0, 0.0, ts=1.0)
    s2 = c2.init(np.array([199.0]), np.array([200.0]))
    assert float(s2.integ[0]) == 0.0                                   # Ki = 0: no integral
    u, s2 = c2.step(s2, np.array([199.99]), np.array([200.0]))
    assert float(u[0]) == 0.0                     # 1e-4 duty from a duty of 0: not sent


def test_from_standard_units():
    c = from_standard(0.1, 50.0, 10.0)
    np.testing.assert_allclose([c.pid_kp[0], c.pid_ki[0], c.pid_kd[0]], [25.5, 0.51, 255.0])


def test_pid_calibrate_closed_form():
    """A first-order heater without sensor lag, sampled finely: the relay switches at the
    thresholds, so the peaks sit at the target and 5 °C below it (amplitude 2.5 °C,
    $K_u = 4/(2.5\\pi)$) and the period is the heating plus the cooling time between them,
    $\\tau \\ln\\frac{T_\\infty - (T - 5)}{T_\\infty - T} + \\tau \\ln\\frac{T - T_a}{T - 5 - T_a}$."""
    tau, gain, amb, target, ts = 100.0, 300.0, 25.0, 200.0, 0.01
    a = np.exp(-ts / tau)
    plant = StateSpace(np.array([[a]]), np.array([[gain * (1 - a)]]), np.array([[1.0]]),
                       ts=ts, u0=np.zeros(1), y0=np.full(1, amb))
    at = pid_calibrate(plant, target)
    hi = amb + gain
    period = tau * (np.log((hi - target + 5) / (hi - target)) + np.log((target - amb) / (target - 5 - amb)))
    assert at.tu == pytest.approx(period, rel=5e-3)
    assert at.ku == pytest.approx(4 / (np.pi * 2.5), rel=5e-3)
    assert at.pid_kp == pytest.approx(0.6 * at.ku * 255)
    assert at.pid_ki == pytest.approx(at.pid_kp / (0.5 * at.tu))
    assert at.pid_kd == pytest.approx(at.pid_kp * 0.125 * at.tu)


def test_c_source_note_header():
    from jthermo.firmware import settings as st

    text = st.c_source(KlipperPID([20.0], [1.0], [100.0]), note="NOT A TUNING TO USE: why\nmore */")
    assert text.startswith("/* NOT A TUNING TO USE: why */\n/* more * / */\n/* Klipper's heater PID")
