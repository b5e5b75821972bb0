"""The `load` scenario of a plant with a measured disturbance (a part-cooling fan): the fan is
stepped as its recording shows, from its median to its recorded extreme and back, and reaches
the plant only; the controller sees the sensors and the set point, never the fan."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

from jthermo.closedloop import model_scenario, simulate  # noqa: E402
from jthermo.control._base import AbstractController  # noqa: E402
from jthermo.models import Envelope, equilibrium_input  # noqa: E402
from jthermo.models._base import StateSpace  # noqa: E402


class HeldInput(AbstractController):
    """A constant input whatever it measures: the loop's plant response is then open loop."""

    u: jax.Array
    ts: float = 1.0

    def init(self, y0, r0):
        return jnp.zeros(())

    def step(self, state, y, r):
        return self.u, state


def fan_plant(n: int):
    """n uncoupled first-order zones (pole 0.95, heater gain 100 °C per unit) that the fan
    cools by 30 °C per unit at steady state; rest at 25 °C."""
    a, b, bw = 0.95, 100.0 * 0.05, -30.0 * 0.05
    eye = np.eye(n)
    return StateSpace(a * eye, b * eye, eye, ts=1.0, Bw=np.full((n, 1), bw), w0=np.zeros(1),
                      y0=np.full(n, 25.0), u0=np.zeros(n))


def fan_envelope(n: int, w_median: float = 0.0, w_max: float = 1.0):
    return Envelope(ts=1.0, y_min=(25.0,) * n, y_max=(110.0,) * n, u_min=(0.0,) * n,
                    u_max=(1.0,) * n, u_mean=(0.5,) * n, u_std=(0.2,) * n, rest=(25.0,) * n,
                    noise_std=(0.0,) * n, w_mean=(0.3,), w_median=(w_median,), w_min=(0.0,),
                    w_max=(w_max,))


@pytest.mark.parametrize("n", [1, 16])
def test_load_steps_the_fan_as_recorded_and_only_the_plant_feels_it(n):
    plant, env = fan_plant(n), fan_envelope(n)
    T = 300
    sc = model_scenario("load", plant, float(T), 0, envelope=env, setpoint=60.0)
    w = np.asarray(sc.d.w)[:, 0]
    on = np.flatnonzero(w > 0.5)
    assert set(np.unique(w)) == {0.0, 1.0}          # the median, then the recorded extreme
    assert 0.2 * T <= on[0] < 0.3 * T and 0.6 * T <= on[-1] + 1 < 0.7 * T
    assert np.all(np.diff(on) == 1)                  # one step on, one step off
    assert np.all(np.asarray(sc.d.dy) == 0)          # no input-referred sink besides
    u_star = equilibrium_input(plant, np.full(n, 60.0), np.zeros(1))
    traj = simulate(plant, HeldInput(jnp.asarray(u_star)), sc)
    # independent recursion of the same plant under the held input and the fan path
    x = np.full(n, 35.0)
    ref = np.empty((T, n))
    for k in range(T):
        ref[k] = 25.0 + x
        x = 0.95 * x + 5.0 * np.asarray(u_star) - 1.5 * w[k]
    np.testing.assert_allclose(np.asarray(traj.temperature), ref, atol=1e-9)
    assert np.asarray(traj.temperature)[on[-1]].max() < 60.0 - 20.0   # the fan cools
    assert np.allclose(np.asarray(traj.u), np.asarray(u_star))        # the fan is no input


def test_load_of_a_fan_mostly_on_steps_it_off():
    plant, env = fan_plant(1), fan_envelope(1, w_median=1.0)
    sc = model_scenario("load", plant, 200.0, 0, envelope=env, setpoint=60.0)
    w = np.asarray(sc.d.w)[:, 0]
    assert set(np.unique(w)) == {0.0, 1.0} and w[0] == 1.0 and w.min() == 0.0


def test_load_without_a_signal_range_keeps_the_input_referred_sink():
    plant = fan_plant(1)
    env = fan_envelope(1)
    old = Envelope.from_dict({**env.to_dict(), "w_min": [], "w_max": []})   # without ranges
    sc = model_scenario("load", plant, 200.0, 0, envelope=old, setpoint=60.0)
    assert np.all(np.asarray(sc.d.w) == 0.0) and np.abs(np.asarray(sc.d.dy)).max() > 0
    given = model_scenario("load", plant, 200.0, 0, envelope=env, setpoint=60.0, load=0.1)
    assert np.all(np.asarray(given.d.w) == 0.0)       # a given load size: the input sink
