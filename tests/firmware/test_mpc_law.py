"""Kalico's model-predictive control: jthermo's `FirmwareMPC` in jthermo's closed loop against
an independent re-implementation of `control_mpc.py` (tests/firmware/reference.py) running the
constants read back from the exported `control: mpc` lines, settled and from a cold start, on
a hot-end plant the constants do not describe exactly; and the law's fixed point."""

import re

import jax
import numpy as np
import pytest

from jthermo.closedloop import model_scenario, simulate
from jthermo.firmware import mpc, settings
from jthermo.firmware.mpc_law import FirmwareMPC
from jthermo.firmware.pid import KlipperPID

from . import reference as ref
from .test_pid_law import hotend

jax.config.update("jax_enable_x64", True)


def read_kalico(text):
    return {k: float(v) for k, v in re.findall(r"^# (\w+): ([-\d.e+]+)$", text, re.MULTILINE)}


@pytest.mark.parametrize("n, kind", [(1, "tracking"), (1, "preheat"), (16, "tracking"),
                                     (16, "preheat")])
def test_exported_constants_match_jthermo_loop(n, kind):
    plant = hotend(n=n)
    rng = np.random.default_rng(n)
    # the plant's rates (250 °C per duty over 120 s, sensor 5 s), each heater's off by up to 20 %
    consts = [mpc.mpc_constants(250.0 / 120.0 * f1, f2 / 120.0, f3 / 5.0, 0.0, 40.0)
              for f1, f2, f3 in rng.uniform(0.8, 1.2, (n, 3))]
    texts = [settings.kalico_cfg(KlipperPID(20.0, 1.0, 100.0), ["extruder"], {"extruder": c})
             for c in consts]
    back = [read_kalico(t) for t in texts]          # what the printer runs
    ctrl = FirmwareMPC.from_constants(back, ts=1.0, u_hold=np.full(n, 0.6))
    sc = model_scenario(kind, plant, 400.0, jax.random.key(5), setpoint=25 + 0.6 * 250)
    traj = simulate(plant, ctrl, sc)
    A, B, C = (np.asarray(m) for m in (plant.A, plant.B, plant.C))
    u0, y0 = np.asarray(plant.u0), np.asarray(plant.y0)
    r, v, dy = (np.asarray(a) for a in (sc.r, sc.v, sc.d.dy))
    start = np.asarray(sc.y0)
    for i in range(n):
        k = back[i]
        s = slice(2 * i, 2 * i + 2)
        settled = kind == "tracking"
        x0 = np.linalg.solve(np.eye(2) - A[s, s], B[s, i] * ((0.6 if settled else 0.0) - u0[i]))
        assert float(y0[i] + C[i, s] @ x0) == pytest.approx(start[i], abs=1e-9)
        first = float(y0[i] + C[i, s] @ x0 + v[0, i] + dy[0, i])
        heater = ref.KalicoMPCHeater(k["heater_power"], k["block_heat_capacity"],
                                     k["sensor_responsiveness"], k["ambient_transfer"],
                                     temp=first)
        ys, us = ref.closed_loop(A[s, s], B[s, i], C[i, s], u0[i], y0[i], heater, r[:, i], x0,
                                 1.0, noise=v[:, i] + dy[:, i], duty0=0.6 if settled else None,
                                 t0=100.0)
        np.testing.assert_allclose(np.asarray(traj.y)[:, i], ys, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.asarray(traj.u)[:, i], us, rtol=0, atol=1e-9)
        assert np.ptp(us) > 0.05          # the loop moved


def test_holds_its_own_model_at_the_target():
    """On the plant the constants describe, without noise, the law settles at the target and
    learns the ambient: the steady error is below 0.05 °C after a cold start."""
    c = mpc.mpc_constants(250.0 / 120.0, 1.0 / 120.0, 1.0 / 5.0, 0.0, 40.0)
    plant = mpc.mpc_model(c, 1.0, ambient=25.0)
    ctrl = FirmwareMPC.from_constants(c, ts=1.0)
    sc = model_scenario("preheat", plant, 600.0, jax.random.key(0), setpoint=200.0)
    sc = sc.__class__(r=sc.r, d=sc.d, v=0.0 * sc.v, y0=sc.y0, kind=sc.kind, window=sc.window,
                      ts=sc.ts)
    y = np.asarray(simulate(plant, ctrl, sc).y)[:, 0]
    assert abs(y[-50:].mean() - 200.0) < 0.05
    assert y.max() < 200.0 + 5.0


def test_bad_constants_refused():
    from jthermo.errors import ControlError

    with pytest.raises(ControlError, match="constants"):
        FirmwareMPC(40.0, -1.0, 0.2, 0.3)
