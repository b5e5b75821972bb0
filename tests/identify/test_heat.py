"""Fits under what heat does (`fit(..., physics="heat")`, `identify.heat`): every family on a
recording whose unmodelled cooling drift runs against a slowly rising heater command.

The record: one heater, one sensor, a first-order plant (gain 20 °C, time constant 30 s) plus
a surroundings drift of -30 °C over the record that nothing measured explains, under a heater
command that ramps up with a small binary excitation. An unconstrained fit lets the heater take
the blame for the cooling (a negative static gain or an unstable model); the heat path may
not."""

from __future__ import annotations

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

from jthermo.data import from_arrays  # noqa: E402
from jthermo.errors import JThermoError  # noqa: E402
from jthermo.identify import fit  # noqa: E402
from jthermo.identify.heat import heat_data  # noqa: E402
from jthermo.identify.positive import fit_positive  # noqa: E402
from jthermo.models import positive  # noqa: E402
from jthermo.models.plausibility import heat_check, is_setpoint_signal  # noqa: E402

FAMILIES = ("arx", "armax", "oe", "bj", "ss", "greybox")


def drift_record(T: int = 500, seed: int = 0, n: int = 1):
    rng = np.random.default_rng(seed)
    t = np.arange(T, dtype=float)
    prbs = np.repeat(rng.integers(0, 2, T // 10 + 1), 10)[:T].astype(float)
    u = np.clip(0.2 + 0.5 * t / T + 0.05 * prbs, 0, 1)[:, None].repeat(n, axis=1)
    a = np.exp(-1 / 30.0)
    x = np.zeros(n)
    y = np.empty((T, n))
    for k in range(T):
        y[k] = 25.0 + x - 30.0 * t[k] / T
        x = a * x + (1 - a) * 20.0 * u[k]
    y += 0.05 * rng.standard_normal(y.shape)
    return from_arrays(u, y, ts=1.0)


def _step_ok(model, n=400):
    s = np.asarray(model.step_response(n))
    return np.all(np.isfinite(s)) and s.min() >= -1e-6 * max(1.0, np.abs(s).max())


def _implausible(data, family):
    try:
        r = fit(data, family, physics="none")
    except JThermoError:
        return True       # refused: no model at all
    return not heat_check(r.model, data)["plausible"]


@pytest.mark.parametrize("family", FAMILIES)
def test_heat_fit_has_non_negative_step_response(family):
    data = drift_record()
    r = fit(data, family)
    assert _step_ok(r.model), f"{family}: a heater step moves the sensor down"
    assert r.extra["physics"]["mode"] == "heat" and r.extra["physics"]["path"]
    if family != "greybox":       # the grey-box bed is positive in both modes
        assert _implausible(data, family), f"{family}: the unconstrained fit looked plausible"


def test_positive_parametrisation_is_metzler_hurwitz_and_positive():
    rng = np.random.default_rng(3)
    for n, ny, nu, nw in ((1, 1, 1, 0), (4, 2, 2, 1), (16, 16, 16, 0)):
        theta = rng.normal(size=positive.n_params(n, ny, nu, nw)) - 2.0
        A, B, C, _ = (np.asarray(m) for m in positive.matrices(jax.numpy.asarray(theta), n, ny, nu, nw))
        off = A - np.diag(np.diag(A))
        assert off.min() >= 0 and B.min() >= 0 and C.min() >= 0
        assert np.max(np.linalg.eigvals(A).real) < 0
        Ad, Bd, _, _ = (np.asarray(m) for m in positive.discrete(jax.numpy.asarray(theta), n, ny,
                                                                 nu, nw, 1.0))
        assert Ad.min() >= -1e-12 and Bd.min() >= -1e-12
        # ZOH against an independent quadrature of the integral of e^{As} B
        s = np.linspace(0, 1, 2001)
        from scipy.linalg import expm

        integ = np.trapezoid([expm(A * v) @ B for v in s], s, axis=0)
        assert np.allclose(Bd, integ, atol=1e-6 * max(1, np.abs(integ).max()))


@pytest.mark.parametrize("n_zones", [1, 4])
def test_positive_fit_recovers_gain(n_zones):
    """Uncoupled nodes, one per sensor, every heater reaching every node: the fit of
    `constrained_polynomial`. Its branches do not depend on the zone count, so 4 zones take the
    16-zone bed's path (largest gain error 0.07 % at 4 zones, 0.5 % at 16, against the 5 %
    asserted) at a sixth of its CPU time; the 16-zone fits of this area: test_guard.py,
    test_pem_padding.py and the grey-box bound below."""
    data = from_arrays(*_clean(n_zones), ts=1.0)
    r = fit_positive(data, n_zones, coupled=False, free_x0=False)
    g = np.asarray(r.model.dcgain())
    assert np.allclose(np.diag(g), 20.0, rtol=0.05)
    assert g.min() >= 0


def _clean(n, T=300, seed=1):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(0, 1, (T // 20 + 1, n)), 20, axis=0)[:T]
    a = np.exp(-1 / 15.0)
    x = np.zeros(n)
    y = np.empty((T, n))
    for k in range(T):
        y[k] = 22.0 + x
        x = a * x + (1 - a) * 20.0 * u[k]
    return u, y + 0.02 * rng.standard_normal(y.shape)


def test_setpoint_signal_left_out_and_constant_input_dropped():
    u, y = _clean(2)
    u[:, 1] = 0.0
    w = np.column_stack([np.full(len(y), 210.0), np.linspace(0, 1, len(y))])
    data = from_arrays(u, y, ts=1.0, w=w, signal_names=["extruder_target_C", "fan_cmd"])
    d, dropped = heat_data(data)
    assert dropped["dropped_signals"] == ["extruder_target_C"]
    assert dropped["dropped_inputs"] == [data.input_names[1]]
    assert d.signal_names == ("fan_cmd",) and d.n_inputs == 1
    r = fit(data, "ss")
    assert r.model.n_inputs == 1 and r.model.n_signals == 1     # the fan: a disturbance
    assert r.extra["physics"]["signals"] == ["fan_cmd"]


def test_tclab_setpoint_column_left_out():
    """A TCLab MPC run logs `w_T1_setpoint`: a set point as much as a printer's target."""
    u, y = _clean(2)
    w = np.column_stack([np.where(np.arange(len(y)) < 150, 40.0, 50.0), np.full(len(y), 21.0)])
    data = from_arrays(u, y, ts=1.0, w=w, signal_names=["T1_setpoint", "T_amb"])
    d, dropped = heat_data(data)
    assert dropped["dropped_signals"] == ["T1_setpoint"] and d.signal_names == ("T_amb",)
    assert not any(map(is_setpoint_signal, ("fan_cmd", "T_amb", "heater_pwm")))
    assert all(map(is_setpoint_signal, ("extruder_target_C", "T2_SetPoint", "bed_set_point")))


def coupled_record(T=600, seed=2):
    """One heater, two sensors: the second warms only through the first (a lag the grey-box
    bed's independent zones cannot follow), the kit at rest at 21 °C for the first 30 s."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([0.0, 0.5, 1.0], T // 60 + 1), 60)[:T, None]
    u[:30] = 0.0
    x = np.zeros(2)
    y = np.empty((T, 2))
    for k in range(T):
        y[k] = 21.0 + x
        x = x + np.array([-x[0] / 120.0 + 0.4 * u[k, 0] - (x[0] - x[1]) / 300.0,
                          (x[0] - x[1]) / 300.0 - x[1] / 900.0])
    return from_arrays(u, y + 0.05 * rng.standard_normal(y.shape), ts=1.0)


def test_greybox_surroundings_no_higher_than_the_coldest_reading():
    from jthermo.identify.greybox import fit_greybox

    data = coupled_record()
    free = fit_greybox(data, use_signals=False)
    assert float(free.model.surroundings) > data.y.min() + 1.0      # carried off by the lag
    assert not heat_check(free.model, data)["plausible"]
    r = fit(data, "greybox")
    assert float(r.model.surroundings) <= data.y.min() + 1e-9
    assert r.extra["surroundings_bounded"] and "bounded" in r.extra["physics"]["path"][0]
    assert heat_check(r.model, data)["plausible"] and _step_ok(r.model)
    assert fit(data, "greybox", physics="none").model.surroundings == free.model.surroundings


@pytest.mark.parametrize("n_zones", [1, 16])
def test_greybox_bound_binds_every_zone(n_zones):
    """16 zones: the bound holds the one constant surroundings of all of them."""
    from jthermo.identify.greybox import fit_greybox

    u, y = _clean(n_zones, T=900)
    y[:, 0] += np.linspace(0.0, 8.0, len(y))      # a drift the first zone reads as warm surroundings
    data = from_arrays(u, y, ts=1.0)
    cap = float(y.min()) - 0.5
    r = fit_greybox(data, use_signals=False, surroundings_max=cap)
    assert float(r.model.surroundings) <= cap + 1e-9
    with pytest.raises(JThermoError, match="surroundings_max must be finite"):
        fit_greybox(data, use_signals=False, surroundings_max=float("nan"))


def step_test(T=500, n=1, start=21.0, on=0.5, seed=0):
    """A heater step test logged as TCLab kits log it: every heater at `on` from the first
    sample (a second, logged heater held at 0), the sensors at `start` there; first order, gain
    30 °C per unit input, time constant 100 s."""
    rng = np.random.default_rng(seed)
    a = np.exp(-1 / 100.0)
    u = np.column_stack([np.full((T, n), on), np.zeros((T, 1))])
    x = np.zeros(n)
    y = np.empty((T, n))
    for k in range(T):
        y[k] = start + x
        x = a * x + (1 - a) * 30.0 * u[k, :n]
    return from_arrays(u, y + 0.03 * rng.standard_normal(y.shape), ts=1.0)


@pytest.mark.parametrize("n", [1, 16])
def test_step_from_rest_puts_rest_before_the_record(n):
    data = step_test(n=n)
    d, info = heat_data(data)
    k = info["rest_samples"]
    assert k >= 30 and d.n_samples == data.n_samples + k and d.t0 == data.t0 - k * data.ts
    assert info["dropped_inputs"] == [data.input_names[n]] and d.n_inputs == n
    assert np.all(d.u[:k] == 0) and np.allclose(d.u[k:], 0.5)
    assert np.all(d.y[:k] == data.y[0]) and np.array_equal(d.y[k:], data.y)
    assert "step from rest" in d.notes[-1]
    again, info2 = heat_data(d)         # a record with its rest varies: nothing more put before
    assert info2["rest_samples"] == 0 and again.n_samples == d.n_samples


@pytest.mark.parametrize("family", ["arx", "oe", "ss", "greybox"])
def test_step_from_rest_fits_its_gain(family):
    data = step_test()
    with pytest.raises(JThermoError, match="constant"):
        fit(data, family, physics="none")       # a constant input: no information as given
    r = fit(data, family)
    assert r.extra["physics"]["rest_samples"] > 0 and r.extra["physics"]["plausible"]
    assert "step from rest" in r.extra["physics"]["path"][0]
    assert _step_ok(r.model)
    assert np.asarray(r.model.dcgain()).ravel()[0] == pytest.approx(30.0, rel=0.1)


def test_constant_record_without_a_step_is_refused_with_the_reason():
    with pytest.raises(JThermoError, match="no heater was on"):
        fit(step_test(on=0.0), "oe")
    hot = step_test()
    hot = hot.replace(y=hot.y[::-1].copy())         # starts hot and cools: not a step from rest
    with pytest.raises(JThermoError, match="does not start at rest"):
        fit(hot, "oe")


def test_plausible_state_space_is_the_unconstrained_one():
    """A record heat explains well: the heat path keeps the family's own fit unchanged."""
    data = from_arrays(*_clean(2), ts=1.0)
    r = fit(data, "ss", (2,))
    free = fit(data, "ss", (2,), physics="none")
    path = r.extra["physics"]["path"]
    assert len(path) == 1 and path[0].startswith("ss n=2: plausible, fit ")     # no positive fit
    assert float(path[0].split("fit ")[1].split(" %")[0]) >= 90.0
    for a, b in ((r.model.A, free.model.A), (r.model.B, free.model.B), (r.model.C, free.model.C)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def bed_record(T=900, seed=4):
    """A printer bed under its own on/off-ish control: heat-up at 0.75 from the room (22 °C),
    a hold at 60 °C while its frame warms slowly (the holding power falls), then heater off.
    Bed node x0 (tau ~ 100 s) loses heat to the room and to the frame x1 (tau ~ 1500 s)."""
    rng = np.random.default_rng(seed)
    x = np.zeros(2)
    u = np.zeros((T, 1))
    y = np.empty((T, 1))
    for k in range(T):
        y[k] = 22.0 + x[0]
        u[k] = 0.0 if k > 750 else (0.75 if y[k, 0] < 60.0 else 0.2 * (60.5 - y[k, 0]).clip(0))
        x = x + np.array([0.6 * u[k, 0] - 0.004 * x[0] - 0.006 * (x[0] - x[1]),
                          0.0015 * (x[0] - x[1]) - 0.0006 * x[1]])
    return from_arrays(u, y + 0.05 * rng.standard_normal(y.shape), ts=1.0)


def test_positive_level_bounded_and_slow_surroundings_fitted():
    """A closed-loop heat-up and hold: the positive state space's level at rest stays at or below
    the coldest reading (+3 sigma), its two nodes find the slow frame, and the model holds its
    recording (covers 22-60 °C)."""
    from jthermo.identify.heat import _mean_fit
    from jthermo.identify.positive import level_cap

    data = bed_record()
    r = fit_positive(data, 2)
    cap = level_cap(np.asarray(data.y))
    assert float(r.model.y0[0]) <= cap[0] + 1e-9
    assert cap[0] < float(np.min(data.y)) + 0.5
    assert heat_check(r.model, data)["plausible"]
    tau = -1.0 / np.log(np.abs(np.linalg.eigvals(np.asarray(r.model.A))))
    assert tau.max() > 5 * tau.min()            # a fast bed and a slow frame
    assert _mean_fit(r.model, data) > 90.0


def _positive_ss(n, ny, nu, seed=0):
    """A discrete positive state space: non-negative A of spectral radius 0.97 at most, B, C
    non-negative, sensor i reading node i."""
    from jthermo.models import StateSpace

    rng = np.random.default_rng(seed)
    A = np.diag(rng.uniform(0.5, 0.95, n)) + 0.02 * rng.uniform(0, 1, (n, n)) * (1 - np.eye(n))
    A *= 0.97 / max(np.abs(np.linalg.eigvals(A)).max(), 0.97)
    C = np.zeros((ny, n))
    C[np.arange(ny), np.arange(ny)] = 1.0
    return StateSpace(A, rng.uniform(0, 1, (n, nu)), C, ts=1.0, y0=rng.uniform(20, 30, ny))


@pytest.mark.parametrize("family", ["arx", "armax", "oe", "bj"])
@pytest.mark.parametrize("n,ny,nu", [(1, 1, 1), (2, 2, 2), (4, 2, 2)])
def test_positive_state_space_as_polynomials_simulates_alike(family, n, ny, nu):
    from jthermo.identify.heat import positive_polynomial

    ss = _positive_ss(n, ny, nu)
    m = positive_polynomial(ss, family)
    u = np.random.default_rng(1).uniform(0, 1, (300, nu))
    A, B, C = (np.asarray(x) for x in (ss.A, ss.B, ss.C))
    x, want = np.zeros(n), np.empty((300, ny))
    for k in range(300):                 # the state recursion from rest, written out
        want[k] = np.asarray(ss.y0) + C @ x
        x = A @ x + B @ u[k]
    np.testing.assert_allclose(np.asarray(m.simulate(u)), want, rtol=0, atol=1e-8)
    assert _step_ok(m)


def test_positive_polynomial_refuses_what_loses_digits_and_many_sensors():
    """16 nodes: the characteristic polynomial of degree 16 loses digits, so no polynomial is
    returned (the constrained first order is the fallback); a 16-sensor record does not try."""
    from jthermo.identify.heat import positive_as_polynomial, positive_polynomial

    assert positive_polynomial(_positive_ss(16, 16, 16), "arx") is None
    r, path = positive_as_polynomial(drift_record(n=16), "arx", "aic")
    assert r is None and "not tried beyond" in path[-1]
    data = coupled_record()
    r, path = positive_as_polynomial(data, "oe", "aic")
    assert r is not None and heat_check(r.model, data)["plausible"] and _step_ok(r.model)
