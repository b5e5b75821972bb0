"""A user's own plant end to end, not the printer: a one-heater first-order-plus-lag record at
Ts = 0.5 s -> fit -> envelope -> design at the set point -> tune -> simulate; set points
beyond reach are one-line errors; model files written before envelopes still load."""

from __future__ import annotations

import equinox as eqx
import numpy as np
import pytest

from jthermo import io
from jthermo.closedloop import make_scenario, model_scenario, run, simulate
from jthermo.control.design import design
from jthermo.data import IOData
from jthermo.errors import ConfigError, ControlError
from jthermo.identify import fit
from jthermo.models import Envelope, equilibrium_input
from jthermo.tune import judge, tune, tune_own_plant
from jthermo.tune.own import tracking_floor

TS, K, TAU, DELAY, REST = 0.5, 80.0, 20.0, 2, 25.0


def record(seed: int = 0, n: int = 1200) -> IOData:
    """Random heater steps in [0, 1] held 15-60 s, through K e^{-s L}/(1 + s TAU), noise 0.05."""
    rng = np.random.default_rng(seed)
    u = np.zeros(n)
    k = 40
    while k < n:
        hold = int(rng.integers(30, 120))
        u[k:k + hold] = rng.uniform(0.0, 1.0)
        k += hold
    a = np.exp(-TS / TAU)
    y = np.full(n, REST)
    for i in range(1, n):
        ui = u[i - 1 - DELAY] if i - 1 - DELAY >= 0 else 0.0
        y[i] = REST + a * (y[i - 1] - REST) + (1 - a) * K * ui
    y = y + 0.05 * rng.standard_normal(n)
    return IOData(u=u[:, None], y=y[:, None], w=np.zeros((n, 0)), ts=TS, input_names=("h",),
                  output_names=("T",), signal_names=())


@pytest.fixture(scope="module")
def fitted():
    res = fit(record(0), "arx", orders=(1, 1, DELAY + 1))
    return res.model, res.envelope


def test_envelope_comes_from_the_recording(fitted):
    model, env = fitted
    data = record(0)
    assert env.ts == TS and env.n_outputs == 1 and env.n_inputs == 1
    assert env.y_min[0] == pytest.approx(data.y.min()) and env.y_max[0] == pytest.approx(data.y.max())
    assert env.rest[0] == pytest.approx(REST, abs=0.2)          # before the first heater step
    assert 0.02 < env.noise_std[0] < 0.1                         # the 0.05 °C added noise
    assert (env.u_min, env.u_max) == ((0.0,), (1.0,))
    assert Envelope.from_dict(env.to_dict()) == env
    r = env.default_setpoint(model)
    assert env.y_min[0] < r[0] < env.y_max[0]
    # the set point's equilibrium input: (r - rest) / K for this plant
    assert equilibrium_input(model, r)[0] == pytest.approx((r[0] - REST) / K, abs=0.02)


def test_scenarios_run_at_the_models_own_sample_time(fitted):
    model, env = fitted
    sc = model_scenario("tracking", model, 60.0, 0, envelope=env, setpoint=70.0)
    assert sc.ts == TS and sc.r.shape == (120, 1) and float(sc.y0[0]) == 70.0
    # set-point changes around the operating point, +delta at 10 %, -delta at 55 %: at most
    # 10 % of the range, and small enough that a first-order loop ten times faster than the
    # plant needs no input beyond [0, 1]: its input jumps by 10 times the equilibrium change,
    # u* + 10 delta / K (up) and u* + delta / K - 20 delta / K (down, 2 delta from r + delta)
    u_star = (70.0 - REST) / K
    delta = min(0.1 * (env.y_max[0] - env.y_min[0]), K * (1.0 - u_star) / 10.0,
                K * u_star / 19.0)
    assert delta < 0.1 * (env.y_max[0] - env.y_min[0])           # the headroom binds here
    r = np.asarray(sc.r[:, 0])
    assert r.max() - 70.0 == pytest.approx(delta, rel=0.03)      # the fit's gain, not K
    delta = r.max() - 70.0
    assert np.allclose(r[:12], 70.0) and np.allclose(r[12:66], 70.0 + delta)
    assert np.allclose(r[66:], 70.0 - delta)
    near_top = model_scenario("tracking", model, 60.0, 0, envelope=env, setpoint=100.0)
    top = REST + K * (1.0 - 0.0)                                  # what full power holds
    assert float(np.max(near_top.r)) < 100.0 + 0.8 * (top - 100.0) + 1.0
    ld = make_scenario("load", model, 60.0, 1, n_rollouts=2, envelope=env, setpoint=70.0)
    assert ld.r.shape == (2, 120, 1) and float(np.min(ld.d.dy)) < -0.5   # a heat sink
    with pytest.raises(ConfigError, match="beyond reach"):
        model_scenario("tracking", model, 60.0, 0, envelope=env, setpoint=130.0)
    with pytest.raises(ConfigError, match="virtual printer"):
        make_scenario("powder", model, 60.0, 0, envelope=env)


def test_design_biases_at_the_setpoint(fitted):
    model, _ = fitted
    c = design("pi_lambda", model, setpoint=65.0)
    assert float(c.u0[0]) == pytest.approx((65.0 - REST) / K, abs=0.02)
    assert c.ts == TS


def test_fit_design_tune_simulate_end_to_end(fitted):
    model, env = fitted
    other = fit(record(1), "arx", orders=(1, 1, DELAY + 1)).model   # another record's fit
    rep = tune_own_plant("pi", model, envelope=env, setpoint=65.0, validation_plant=other,
                         rollouts=2, steps=3, duration=200.0, classical=("pi_lambda",))
    assert rep["setpoints"] == [65.0] and rep["ts"] == TS
    assert set(rep["saturated_fraction"]) == {"tracking", "load", "preheat"}
    assert all(0.0 <= v < 0.9 for v in rep["saturated_fraction"].values())
    assert rep["validation"]["verdict"] == "settled"
    # a designed PI starts with the set-point weight as a tuned leaf (b = 1 would never move)
    assert rep["tuned"].b_angle is not None and 0.0 <= float(np.max(np.asarray(rep["tuned"].b))) <= 1.0
    # what the tuning did is reported: whether the gains moved, and the heaters' floor
    assert isinstance(rep["moved"], bool) and "passed" in rep["guard"]
    assert 0.0 < rep["startup_floor_mse"] <= rep["scenarios"]["tuned"]["preheat"]["mse"]
    assert 0.0 < rep["validation"]["startup_floor_mse"] <= min(
        v["preheat"]["mse"] for v in rep["validation"]["scenarios"].values())
    # the set-point changes' bound: full-power floor plus the recording's noise variance
    v = rep["validation"]
    assert v["noise_mse"] == pytest.approx(env.noise_std[0] ** 2)
    assert v["tracking_bound_mse"] == pytest.approx(v["tracking_floor_mse"] + v["noise_mse"])
    assert v["best_pid_type_tracking"] == "pi_lambda" and isinstance(v["bang_bang"], list)
    assert rep["validation"]["startup_overshoot_C"] >= 0.0
    # the cost terms carry their weights' names; normalised, each weighs in at the start
    terms = rep["scenarios"]["start"]["tracking"]["terms"]
    assert set(terms) == {"tracking", "uniformity", "effort", "window", "overshoot"}
    assert rep["normalised_weights"]["effort"] == pytest.approx(
        rep["weights"]["effort"] / rep["term_scales"]["effort"])
    out = run("tracking", rep["tuned"], other, rollouts=2, duration=200.0,
              scenario_kw={"envelope": env, "setpoint": 65.0})
    assert out["setpoints"] == [65.0] and out["ts"] == TS
    assert out["metrics"]["settling_time_s"] < 200.0 and out["metrics"]["overshoot_C"] < 4.0
    with pytest.raises(ConfigError, match="beyond reach"):
        tune_own_plant("pi", model, envelope=env, setpoint=500.0, steps=1, rollouts=1)


def test_judge_rejects_saturated_or_unsettled_loops():
    ok = {"mse": 1.0, "saturated_fraction": 0.1, "settling_time_s": 50.0}
    assert judge({"tracking": ok}, 100.0) is None
    assert "input limit" in judge({"tracking": {**ok, "saturated_fraction": 1.0}}, 100.0)
    assert "does not settle" in judge({"preheat": {**ok, "settling_time_s": 100.0}}, 100.0)
    assert "non-finite" in judge({"load": {**ok, "mse": float("nan")}}, 100.0)
    # a bang-bang loop: at a limit 30 % of the set-point changes or the load (at most 25 %);
    # the start-up step is at full power by nature, so only 90 % fails there
    assert "at most 25 %" in judge({"tracking": {**ok, "saturated_fraction": 0.3}}, 100.0)
    assert "at most 25 %" in judge({"load": {**ok, "saturated_fraction": 0.3}}, 100.0)
    assert judge({"preheat": {**ok, "saturated_fraction": 0.3}}, 100.0) is None
    with pytest.raises(ControlError):
        raise ControlError(judge({"tracking": {**ok, "saturated_fraction": 1.0}}, 100.0))


def test_model_files_without_an_envelope_still_work(fitted, tmp_path):
    model, env = fitted
    io.save(model, tmp_path / "old.jtm", meta={"family": "arx"})
    assert io.load_envelope(tmp_path / "old.jtm") is None
    io.save(model, tmp_path / "new.jtm", meta={"envelope": env.to_dict()})
    assert io.load_envelope(tmp_path / "new.jtm") == env
    stand_in = Envelope.from_model(model)
    assert stand_in.ts == TS and stand_in.rest[0] == pytest.approx(REST, abs=1.0)


def test_fit_result_prints_a_readable_summary():
    res = fit(record(0), "arx", orders=(1, 1, DELAY + 1))
    text = repr(res)
    assert text == res.summary() and "covariance" not in text and "Array" not in text
    assert "arx" in text and "'nk': 3" in text and "converged" in text
    gain = float(text.split("DC gain (°C per input): [[")[1].split("]]")[0])
    assert gain == pytest.approx(K, rel=0.02)
    assert "poles (3, z-plane, Ts 0.5 s)" in text


def test_tuning_moves_a_detuned_pid(fitted):
    """The gradient reaches the PID's gains through its clip and conditional integration: from
    a Ziegler–Nichols PID detuned to a quarter of its gain, tuning on the tracking step lowers
    the cost and raises the gain; no classical-level loop beats the full-power floor."""
    model, env = fitted
    kw = {"envelope": env, "setpoint": 65.0}
    zn = design("pid_relay", model, setpoint=65.0)
    slow = eqx.tree_at(lambda c: c.kp, zn, zn.kp / 4)
    res = tune(slow, model, kind="tracking", rollouts=2, steps=15, lr=0.1, duration=150.0,
               guard=False, normalise=False, scenario_kw=kw)
    assert res.tuned_cost < 0.9 * res.start_cost
    assert float(res.controller.kp[0]) > 1.2 * float(slow.kp[0])
    sc = model_scenario("preheat", model, 150.0, 0, **kw)
    floor = tracking_floor(model, env, 65.0, 150.0, 0)
    for c in (zn, slow, res.controller):
        e = np.asarray(simulate(model, c, sc).y) - np.asarray(sc.r)
        assert 0.0 < floor <= float(np.mean(e ** 2))


def test_tuning_start_bounds_the_noise_gain(fitted):
    """A Ziegler–Nichols PID whose measurement noise alone would swing the input across its
    limits starts tuning detuned (kp s, ti / s, td kept, filter >= one sample) until the input
    noise is at most NOISE_SHARE of the headroom; on a quiet recording it is only given its
    set-point weight."""
    import dataclasses

    from jthermo.tune.own import NOISE_SHARE, detuned, noise_gain, tuning_start

    model, env = fitted
    zn = design("pid_relay", model, setpoint=65.0)
    u_star = (65.0 - REST) / K
    room = min(u_star, 1.0 - u_star)
    quiet = tuning_start(zn, model, env, 65.0)
    assert float(noise_gain(zn)[0]) * env.noise_std[0] < NOISE_SHARE * room   # 0.05 C noise
    assert np.allclose(quiet.kp, zn.kp) and np.allclose(quiet.ti, zn.ti)
    assert float(quiet.b[0]) == pytest.approx(0.95)
    noisy = dataclasses.replace(env, noise_std=(2.0,))
    c = tuning_start(zn, model, noisy, 65.0)
    s = float(c.kp[0] / zn.kp[0])
    assert 0.0 < s < 1.0 and float(c.ti[0]) == pytest.approx(float(zn.ti[0]) / s)
    assert float(c.td[0]) == pytest.approx(float(zn.td[0]))
    assert float(c.td[0]) / c.n_filter >= c.ts - 1e-12                   # filter >= 1 sample
    swing = float(noise_gain(c)[0]) * 2.0
    assert swing == pytest.approx(NOISE_SHARE * room, rel=0.05)          # the largest such s
    assert float(noise_gain(detuned(zn, 1.1 * s))[0]) * 2.0 > NOISE_SHARE * room
    pi = design("pi_lambda", model, setpoint=65.0)
    assert float(noise_gain(pi)[0]) == pytest.approx(float(pi.kp[0]))


def test_change_scale_keeps_a_ten_times_faster_loop_inside_the_limits():
    """Two decoupled unit-gain heaters at r = (0.3, 0.5) °C (u* = r): changes of 0.1 °C need
    u* + 10 g going up and u* + 0.1 - 2 (10 g) going down, g = 0.1 the equilibrium change; the
    down step of loop 1 binds at s = 0.3 / 1.9. Coupling moves g to G(1)^-1 delta."""
    from jthermo.models import StateSpace
    from jthermo.models.envelope import change_scale

    env = Envelope(ts=1.0, y_min=(0.0, 0.0), y_max=(1.0, 1.0), u_min=(0.0, 0.0),
                   u_max=(1.0, 1.0), u_mean=(0.3, 0.5), u_std=(0.1, 0.1), rest=(0.0, 0.0),
                   noise_std=(0.0, 0.0))
    plant = StateSpace(0.9 * np.eye(2), 0.1 * np.eye(2), np.eye(2))
    assert change_scale(plant, env, (0.3, 0.5), 0.1) == pytest.approx(0.3 / 1.9)
    assert change_scale(plant, env, (0.3, 0.5), 0.001) == 1.0              # small enough
    assert change_scale(plant, env, (0.3, 0.5), 0.1, speedup=1.0) == pytest.approx(1.0)
    coupled = StateSpace(0.9 * np.eye(2), 0.1 * np.array([[1.0, 0.5], [0.0, 1.0]]), np.eye(2))
    g = np.linalg.solve([[1.0, 0.5], [0.0, 1.0]], [0.1, 0.1])              # [0.05, 0.1]
    u = np.linalg.solve([[1.0, 0.5], [0.0, 1.0]], [0.3, 0.5])              # [0.05, 0.5]
    assert change_scale(coupled, env, (0.3, 0.5), 0.1) == pytest.approx(
        min(u / (19 * g)))


def test_inputs_recorded_beyond_power_fractions_are_refused_for_a_closed_loop():
    """A heater logged in % (0-100): the loop clips inputs to [0, 1], so every set point was
    out of reach while `simulate` exited 0 (input at 1 throughout, 25 °C error)."""
    from jthermo.models import StateSpace

    plant = StateSpace(0.9 * np.eye(1), 0.001 * np.eye(1), np.eye(1))
    env = Envelope(ts=1.0, y_min=(20.0,), y_max=(60.0,), u_min=(0.0,), u_max=(100.0,),
                   u_mean=(30.0,), u_std=(10.0,), rest=(20.0,), noise_std=(0.1,))
    with pytest.raises(ConfigError, match="inputs span 0 to 100; .* rescale the inputs"):
        env.check(plant)
    with pytest.raises(ConfigError, match="inputs span 0 to 100"):
        model_scenario("tracking", plant, 100.0, 0, envelope=env, setpoint=(40.0,))
