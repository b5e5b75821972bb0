"""The two-state hot-end model of Marlin's / Kalico's MPC: the exported constants, read back
from the `M306` line and Kalico's keys, reproduce the fitted model's step response (closed
form, re-derived here) to 1e-6 °C; the grey-box fit recovers known constants from a record
simulated here (its own integrator); a record that does not move the heater is refused."""

import re

import numpy as np
import pytest

from jthermo.errors import ControlError
from jthermo.firmware import mpc, settings
from jthermo.firmware.pid import KlipperPID


def step_closed_form(h, a, R, t):
    """Sensor rise (°C above ambient) for full duty from rest: block
    $x_b = (h/a)(1 - e^{-at})$, sensor $x_s = (h/a)[1 - (R e^{-at} - a e^{-Rt})/(R - a)]$."""
    return (h / a) * (1.0 - (R * np.exp(-a * t) - a * np.exp(-R * t)) / (R - a))


def parse_m306(line):
    return {k: float(v) for k, v in re.findall(r"\b([PCRAF])([-\d.e+]+)", line)}


RATES = [(2.6, 0.0063, 0.039, 0.0011), (0.9, 0.004, 0.2, 0.0), (5.0, 0.02, 0.05, 0.01)]


@pytest.mark.parametrize("h, a, R, af", RATES)
def test_exported_constants_reproduce_step_response(h, a, R, af):
    c = mpc.mpc_constants(h, a, R, af, heater_power=47.5)
    t = np.arange(0, 1200.0, 0.3)
    ref = step_closed_form(h, a, R, t)                    # the fitted model's response
    m = parse_m306(settings.marlin_mpc(c))
    got = step_closed_form(m["P"] / m["C"], m["A"] / m["C"], m["R"], t)
    assert np.max(np.abs(got - ref)) < 1e-6
    assert (m["F"] - m["A"]) / m["C"] == pytest.approx(af, abs=1e-9)
    # Kalico's keys (commented-out alternative in the kalico file)
    text = settings.kalico_cfg(KlipperPID(20.0, 1.0, 100.0), ["extruder"], {"extruder": c})
    k = {kk: v for kk, v in re.findall(r"^# (\w+): ([-\d.e+]+)$", text, re.MULTILINE)}
    got = step_closed_form(float(k["heater_power"]) / float(k["block_heat_capacity"]),
                           float(k["ambient_transfer"]) / float(k["block_heat_capacity"]),
                           float(k["sensor_responsiveness"]), t)
    assert np.max(np.abs(got - ref)) < 1e-6
    # and the library's state space of the constants is the same model
    ss = mpc.mpc_model(c, 0.3, ambient=0.0)
    assert np.max(np.abs(np.asarray(ss.step_response(len(t)))[:, 0, 0] - ref)) < 1e-6


def record(h, a, R, af, ta, ts=0.3, sub=60, seed=0):
    """Heat-up, hold, cool-down, the fan at full for the second half; forward Euler on
    `sub` sub-steps per sample (an integrator of its own)."""
    n = 4000
    u = np.zeros(n)
    u[:400] = 1.0
    u[400:1400] = 0.45
    u[2000:2400] = 1.0
    u[2400:3200] = 0.5
    fan = (np.arange(n) >= 2000).astype(float)
    xb = xs = 0.0
    y = np.empty(n)
    dt = ts / sub
    for k in range(n):
        y[k] = xs + ta
        for _ in range(sub):
            xb, xs = (xb + dt * (h * u[k] - (a + af * fan[k]) * xb), xs + dt * R * (xb - xs))
    return y + np.random.default_rng(seed).normal(0, 0.05, n), u, fan


def test_fit_recovers_constants():
    h, a, R, af, ta = 2.6, 0.0063, 0.039, 0.0015, 24.0
    y, u, fan = record(h, a, R, af, ta)
    res = mpc.fit_two_state(y, u, fan, ts=0.3, heater_power=40.0)
    rt = res["rates"]
    assert rt["heating_rate"] == pytest.approx(h, rel=0.02)
    assert rt["ambient_rate"] == pytest.approx(a, rel=0.02)
    assert rt["sensor_responsiveness"] == pytest.approx(R, rel=0.02)
    assert rt["fan_rate"] == pytest.approx(af, rel=0.05)
    assert res["ambient_C"] == pytest.approx(ta, abs=0.5)
    assert res["fan"] and res["rms_C"] < 0.1
    c = res["constants"]
    assert c["block_heat_capacity"] == pytest.approx(40.0 / h, rel=0.02)
    sim = mpc.simulate(c, u, fan, ts=0.3, ambient=res["ambient_C"], y0=y[0])
    assert np.sqrt(np.mean((sim - y) ** 2)) < 0.1
    # the fitted model's own step response against the exported M306 line's
    t = np.arange(0, 1200.0, 0.3)
    m = parse_m306(settings.marlin_mpc(c))
    ref = step_closed_form(rt["heating_rate"], rt["ambient_rate"], rt["sensor_responsiveness"], t)
    got = step_closed_form(m["P"] / m["C"], m["A"] / m["C"], m["R"], t)
    assert np.max(np.abs(got - ref)) < 1e-6


def test_flat_record_refused():
    with pytest.raises(ControlError, match="does not move"):
        mpc.fit_two_state(np.full(100, 200.0), np.full(100, 0.4), ts=1.0)
