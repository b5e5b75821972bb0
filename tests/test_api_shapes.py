"""The Python API as scripts call it: a value of the wrong size at a public entry point
(`design`, `make_scenario`, `simulate`, `rollouts`, `tune`) is a jthermo error with one line
naming what was given and what was expected, never a NumPy/JAX broadcasting error; and what
they return prints readably (a model: sizes, DC gain, poles; a controller: its gains)."""

import re

import jax
import numpy as np
import pytest

from jthermo import closedloop
from jthermo.control import design
from jthermo.data import from_arrays
from jthermo.errors import ConfigError, JThermoError
from jthermo.identify import fit
from jthermo.printer import make_printer
from jthermo.tune import tune


def _model(zones: int, seed: int = 0):
    """ARX(1,1,1) of a simulated first-order bed with `zones` heaters and sensors."""
    rng = np.random.default_rng(seed)
    T = 400
    u = np.repeat(rng.uniform(0, 1, (T // 20, zones)), 20, axis=0)
    y = np.full((T, zones), 25.0)
    for k in range(1, T):
        y[k] = 25.0 + 0.95 * (y[k - 1] - 25.0) + 2.0 * u[k - 1]
    return fit(from_arrays(u, y + 0.01 * rng.standard_normal((T, zones)), ts=1.0), "arx",
               (1, 1, 1)).model


@pytest.fixture(scope="module")
def loops():
    m1, m2 = _model(1), _model(2)
    p2 = make_printer(2, seed=0)
    return {"m1": m1, "m2": m2, "p2": p2,
            "pi1": design("pi_lambda", m1, setpoint=60.0),
            "pi2": design("pi_lambda", m2, setpoint=60.0),
            "sc_m2": closedloop.make_scenario("tracking", m2, 30.0, setpoint=60.0),
            "sc_p2": closedloop.make_scenario("tracking", p2, 30.0)}


def _one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text and isinstance(exc.value, JThermoError)
    return text


#: a 1-zone PI on 2 outputs: its step fails to trace or hands back the wrong number of inputs
WRONG_PI = r"the controller DiagonalPI (does not fit a plant with 2 outputs|returns \(1,\) inputs, the plant takes 2)"

CASES = {
    "design_setpoint_size": (lambda L: design("pi_lambda", L["m2"], setpoint=[60.0, 60.0, 60.0]),
                             r"design: setpoint needs one value or 2 \(one per output\), got shape \(3,\)"),
    "design_setpoint_matrix": (lambda L: design("lqg", L["m2"], setpoint=np.full((2, 2), 60.0)),
                               r"design: setpoint needs one value or 2 .* got shape \(2, 2\)"),
    "scenario_setpoint_size": (
        lambda L: closedloop.make_scenario("tracking", L["m2"], 30.0, setpoint=[60.0] * 3),
        r"scenario: setpoint needs one value or 2 \(one per output\), got shape \(3,\)"),
    "printer_scenario_on_model": (
        lambda L: closedloop.simulate(L["m2"], L["pi2"], L["sc_p2"]),
        r"simulate: the scenario was built for the virtual printer, the plant is a fitted model"),
    "model_scenario_on_printer": (
        lambda L: closedloop.simulate(L["p2"], L["pi2"], L["sc_m2"]),
        r"simulate: the scenario was built for a fitted model, the plant is the virtual printer"),
    "scenario_outputs": (
        lambda L: closedloop.simulate(L["m1"], L["pi1"], L["sc_m2"]),
        r"simulate: the scenario has set points for 2 outputs, the plant has 1"),
    "controller_zones": (
        lambda L: closedloop.simulate(L["m2"], L["pi1"], L["sc_m2"]),
        r"simulate: " + WRONG_PI),
    "controller_zones_batched": (
        lambda L: closedloop.rollouts(L["m2"], L["pi1"], closedloop.make_scenario(
            "tracking", L["m2"], 30.0, setpoint=60.0, n_rollouts=2)),
        r"simulate: " + WRONG_PI),
    "x0_shape": (
        lambda L: closedloop.simulate(L["m2"], L["pi2"], L["sc_m2"], x0=np.zeros(5)),
        r"simulate: x0 has shapes \[\(5,\)\], the plant's state has \[\(2,\)\]"),
    "x0_printer_state": (
        lambda L: closedloop.simulate(L["p2"], L["pi2"], L["sc_p2"], x0=np.zeros(2)),
        r"simulate: x0 has shapes \[\(2,\)\], the plant's state has \[\(2,\), "),
    "tune_controller_zones": (
        lambda L: tune(L["pi1"], L["m2"], kind=("tracking",), rollouts=1, steps=1, duration=30.0),
        r"tune: " + WRONG_PI),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_shape_mistakes_are_one_line_errors(loops, case):
    call, message = CASES[case]
    with pytest.raises(ConfigError) as exc:
        call(loops)
    assert re.search(message, _one_line(exc)), str(exc.value)


def test_right_shapes_still_run(loops):
    """The checks pass what is right: a scalar or per-output set point, a matching loop (also
    under jit, where the check sees traced values)."""
    assert design("pi_lambda", loops["m2"], setpoint=[60.0, 65.0]) is not None
    traj = jax.jit(closedloop.simulate)(loops["m2"], loops["pi2"], loops["sc_m2"])
    assert traj.u.shape == (30, 2) and bool(np.all(np.isfinite(traj.y)))
    sc = closedloop.make_scenario("tracking", loops["p2"], 20.0)
    assert closedloop.simulate(loops["p2"], loops["pi2"], sc).y.shape == (20, 2)
    for plant, scen in ((loops["p2"], sc), (loops["m2"], loops["sc_m2"])):    # a given x0
        x0 = closedloop.initial_state(plant, scen)
        assert closedloop.simulate(plant, loops["pi2"], scen, x0=x0).y.shape[1] == 2


def test_model_prints_gain_and_poles(loops):
    m = loops["m2"]
    text = repr(m)
    assert text.splitlines()[0] == "Polynomial: 2 inputs -> 2 outputs, Ts 1 s"
    gain = np.array(eval(text.split("DC gain (°C per input): ")[1].splitlines()[0]))
    np.testing.assert_allclose(gain, np.asarray(m.dcgain()), atol=1e-4)
    assert abs(gain[0, 0] - 40.0) < 1.0                         # 2 / (1 - 0.95)
    assert "poles (2, z-plane, Ts 1 s): [(0.95" in text and "f64[" not in text
    # inside jit the model holds tracers: printing falls back to the tree, never fails
    seen = []
    jax.jit(lambda mm: seen.append(repr(mm)) or mm.a)(m)
    assert seen and seen[0].startswith("Polynomial(")


def test_controller_prints_its_gains(loops):
    pi = loops["pi2"]
    text = repr(pi)
    assert text.startswith("DiagonalPI(") and "f64[" not in text
    for name in ("kp", "ti", "u0"):
        shown = text.split(f"{name}=Array(")[1].split(", dtype")[0]
        np.testing.assert_allclose(np.array(eval(shown)), np.asarray(getattr(pi, name)), rtol=1e-6)
