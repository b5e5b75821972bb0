"""The virtual printer: exact where physics can be checked exactly, right in direction elsewhere."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.data import load_csv, save_csv
from jthermo.errors import ConfigError
from jthermo.models import BedModel
from jthermo.printer import (
    EFFECTS,
    POWDERS,
    PrinterDisturbance,
    disturbances,
    generate,
    make_printer,
    simulate_open_loop,
    steady_state,
)

N = 4
T_SHORT = 400


def _u(T=T_SHORT, n=N, seed=0):
    rng = np.random.default_rng(seed)
    hold = 10
    lv = rng.integers(0, 2, size=(T // hold + 1, n)) * 0.4 + 0.3
    return jnp.asarray(np.repeat(lv, hold, axis=0)[:T])


def _bed(y):
    return np.asarray(y)[:, :N]


def test_effect_free_equals_linear_bed_model():
    p = make_printer(N, seed=3)
    par = p.linear_bed_parameters()
    m = BedModel.from_physical(np.asarray(par["capacity"]), np.asarray(par["loss"]),
                               np.asarray(par["gain"]), ts=1.0)
    T = 3600
    u = _u(T)
    x0 = p.initial_state(jnp.full(N, 170.0))
    y, _ = simulate_open_loop(p, u, None, x0)
    w = np.full((T, 1), float(p.surroundings))
    ym = m.simulate(u, w, x0=x0.z)
    np.testing.assert_allclose(y, ym, rtol=0, atol=1e-9)


def test_effect_free_matches_scipy_zoh_and_analytic_steady_state():
    from scipy import signal
    p = make_printer(N, seed=1)
    C, G, n = (np.asarray(a) for a in (p.capacity, p.loss, p.gain))
    Ts = float(p.surroundings)
    A = -np.diag(G / C)
    B = np.concatenate([n / C[:, None], (G / C)[:, None]], axis=1)
    Ad, Bd, *_ = signal.cont2discrete((A, B, np.eye(N), np.zeros((N, N + 1))), 1.0, method="zoh")
    u = np.asarray(_u(T_SHORT))
    x = np.full(N, 160.0)
    ref = []
    for k in range(T_SHORT):
        ref.append(x)
        x = Ad @ x + Bd @ np.r_[u[k], Ts]
    y, _ = simulate_open_loop(p, jnp.asarray(u), None, p.initial_state(jnp.full(N, 160.0)))
    np.testing.assert_allclose(y, np.array(ref), atol=1e-9)
    # analytic steady state: T = Ts + G^-1 n u
    uc = jnp.full(N, 0.45)
    xs = steady_state(p, uc)
    np.testing.assert_allclose(xs.z, Ts + (n @ np.asarray(uc)) / G, rtol=1e-12)
    # and it is a fixed point of one sample
    np.testing.assert_allclose(p.step(xs, uc).z, xs.z, atol=1e-10)


def test_energy_balance_closes():
    """Stored heat change = heater + laser energy - losses (lateral conduction cancels)."""
    effects = ["lateral_conduction", "laser_exposure"]
    p = make_printer(N, effects, seed=2)
    fine = make_printer(N, effects, seed=2, ts=0.01)
    K, sub = 40, 100
    u = _u(K)
    d = disturbances(p, K, jax.random.key(0), laser=True)
    rep = lambda a: jnp.repeat(a, sub, axis=0)
    x0 = p.initial_state()
    _, coarse = simulate_open_loop(p, u, d, x0)
    _, temps = simulate_open_loop(fine, rep(u), jax.tree.map(rep, d), x0)
    temps = np.asarray(temps)
    C, G, n = (np.asarray(a) for a in (p.capacity, p.loss, p.gain))
    Ts = float(p.surroundings)
    mid = 0.5 * (temps[1:] + temps[:-1])
    E_loss = 0.01 * np.sum(G * (mid - Ts))
    E_in = 0.01 * (np.sum(np.asarray(rep(u))[:-1] @ n.T) + np.sum(np.asarray(rep(d.laser))[:-1]))
    stored = float(np.sum(C * (temps[-1] - temps[0])))
    assert abs(stored - (E_in - E_loss)) < 1e-4 * E_in
    # the coarse printer is the fine one sampled (both exact ZOH)
    np.testing.assert_allclose(coarse, temps[::sub], atol=1e-8)


def _steady_hot(p, u=0.7):
    return np.asarray(steady_state(p, u).z[:N])


def test_effects_change_the_response_in_the_physical_direction():
    base = make_printer(N, seed=0)
    u = _u(T_SHORT)
    x0 = base.initial_state()
    y0, _ = simulate_open_loop(base, u, None, x0)
    y0 = _bed(y0)

    # radiation: the loss grows as T^4, so the hotter the bed the less one more unit of
    # input warms it (`loss` is matched at the window centre)
    rad = make_printer(N, ["radiative_loss"], seed=0)
    hot = lambda p: _steady_hot(p, 0.8) - _steady_hot(p, 0.7)
    cold = lambda p: _steady_hot(p, 0.3) - _steady_hot(p, 0.2)
    assert np.all(hot(rad) < hot(base)) and np.all(hot(rad) < cold(rad))
    assert np.all(_steady_hot(rad, 0.9) < _steady_hot(base, 0.9))
    # lateral conduction: zones closer together at a non-uniform steady state
    lat = make_printer(N, ["lateral_conduction"], seed=0)
    uu = jnp.array([0.9, 0.1, 0.1, 0.1])
    spread = lambda p: np.ptp(np.asarray(steady_state(p, uu).z[:N]))
    assert spread(lat) < spread(base)
    # heater lag and input delay: a later response to a step, same end point
    us = base.steady_input()
    step = jnp.concatenate([jnp.broadcast_to(us, (50, N)), jnp.broadcast_to(us + 0.25, (350, N))])
    yb, _ = simulate_open_loop(base, step, None, base.initial_state())
    for eff in ("heater_lag", "input_delay"):
        p = make_printer(N, [eff], seed=0)
        y, _ = simulate_open_loop(p, step, None, p.initial_state())
        assert np.all(y[55] < yb[55] - 1e-3), eff
        np.testing.assert_allclose(y[-1], yb[-1], atol=0.05)
    # delay: nothing happens for exactly delay_s samples
    p = make_printer(N, {"input_delay": {"delay_s": 3}}, seed=0)
    y, _ = simulate_open_loop(p, step, None, p.initial_state())
    np.testing.assert_allclose(y[:54], np.broadcast_to(y[0], (54, N)), atol=1e-9)
    np.testing.assert_allclose(y[54:], yb[51:-3], atol=1e-9)
    # heat accumulation: a slow mode; the response keeps creeping after the fast one is done
    p = make_printer(N, ["heat_accumulation"], seed=0)
    y, _ = simulate_open_loop(p, step, None, p.initial_state())
    frac = lambda p, y: (y[-1] - y[49]) / (steady_state(p, us + 0.25).z[:N] - y[49])
    # `loss` is the steady-state loss for a uniform bed: end points agree up to the mixing
    np.testing.assert_allclose(steady_state(p, us + 0.25).z[:N], steady_state(base, us + 0.25).z, atol=0.5)
    assert np.all(frac(base, yb) > 0.95) and np.all(frac(p, y) < 0.9)
    # input nonlinearity u^1.5: more power above the nominal input, less below
    p = make_printer(N, ["input_nonlinearity"], seed=0)
    assert np.all(_steady_hot(p, 0.8) > _steady_hot(base, 0.8))
    assert np.all(_steady_hot(p, 0.2) < _steady_hot(base, 0.2))
    # recoat cools, laser heats, an offset biases the reading not the temperature
    T = T_SHORT
    for eff, sign in (("recoat_cooling", -1), ("laser_exposure", +1)):
        p = make_printer(N, [eff], seed=0)
        d = disturbances(p, T, jax.random.key(0))
        _, temps = simulate_open_loop(p, u, d, p.initial_state())
        diff = _bed(temps) - y0
        assert sign * diff.sum() > 0 and np.all(sign * diff >= -1e-9), eff
    p = make_printer(N, ["recoat_cooling"], seed=0)
    d = disturbances(p, T, jax.random.key(0))
    _, temps = simulate_open_loop(p, jnp.full((T, N), 0.5), d, p.initial_state())
    first = int(np.argmax(np.asarray(d.recoat)))
    drop = np.asarray(temps[first - 1] - temps[first + 10])
    assert np.all((drop > 1.5) & (drop < 3.5))    # about drop_C = 3 at the window centre
    p = make_printer(N, ["sensor_offset"], seed=0)
    y, temps = simulate_open_loop(p, u, None, p.initial_state())
    np.testing.assert_allclose(_bed(temps), y0, atol=1e-9)
    np.testing.assert_allclose(_bed(y) - y0, np.broadcast_to(p.effects["sensor_offset"]["offsets_C"], y0.shape), atol=1e-9)
    # ambient variation: the surroundings move and the bed follows
    p = make_printer(N, {"ambient_variation": {"amplitude_C": 5.0, "period_s": 400.0}}, seed=0)
    d = disturbances(p, T, jax.random.key(1))
    _, temps = simulate_open_loop(p, u, d, p.initial_state())
    c = np.corrcoef(np.asarray(d.ambient)[:-20], (_bed(temps) - y0).mean(1)[20:])[0, 1]
    assert c > 0.8


def test_powders_and_areas():
    pa12, pa11 = make_printer(N), make_printer(N, powder="PA11")
    assert float(pa11.capacity.mean()) > float(pa12.capacity.mean())
    assert POWDERS["PA12"].window == (172.0, 176.0)
    for p in (pa12, pa11):
        u = p.steady_input()
        assert np.all((np.asarray(u) > 0.3) & (np.asarray(u) < 0.7))   # window reachable mid-range
    pa = make_printer(N, areas=True)
    assert pa.n_inputs == pa.n_outputs == N + 3
    x = pa.initial_state()
    np.testing.assert_allclose(pa.step(x, pa.steady_input()).z, x.z, atol=1e-9)
    # the wall heater warms the wall, and through it the bed
    u = jnp.broadcast_to(pa.steady_input(), (300, N + 3)).at[:, N].add(0.3)
    y, _ = simulate_open_loop(pa, u, None, x)
    assert float(y[-1, N] - y[0, N]) > 1.0 and float(jnp.mean(y[-1, :N] - y[0, :N])) > 0.0


def test_generate_writes_the_csv_contract(tmp_path):
    p = make_printer(N, ["recoat_cooling", "sensor_noise"], seed=0)
    data = generate(p, duration=300, seed=5)
    assert data.u.shape == (300, N) and data.y.shape == (300, N)
    assert data.signal_names == ("ambient", "recoat")
    assert np.all((data.u >= 0) & (data.u <= 1))
    lo, hi = POWDERS["PA12"].window
    assert lo - 8 < data.y.mean() < hi + 8
    assert data.w[:, 1].sum() == len(range(20, 300, 60))
    path = tmp_path / "d.csv"
    save_csv(data, path)
    back = load_csv(path)
    np.testing.assert_allclose(back.y, data.y, atol=1e-6)
    assert back.input_names == tuple(str(i + 1) for i in range(N))
    # same seed, same data; another seed, other data
    again = generate(p, duration=300, seed=5)
    np.testing.assert_array_equal(again.y, data.y)
    other = generate(p, duration=300, seed=6)
    assert not np.allclose(other.y, data.y)


def test_bad_input_raises_config_error():
    with pytest.raises(ConfigError, match="unknown effect `radiation`"):
        make_printer(N, ["radiation"])
    with pytest.raises(ConfigError, match="has no parameter `tau`"):
        make_printer(N, {"heater_lag": {"tau": 3}})
    with pytest.raises(ConfigError, match="unknown powder"):
        make_printer(N, powder="PLA")
    with pytest.raises(ConfigError, match="zones must be"):
        make_printer(0)
    with pytest.raises(ConfigError, match="whole number of samples"):
        make_printer(N, {"input_delay": {"delay_s": 1.5}})
    with pytest.raises(ConfigError, match="must be > 0"):
        make_printer(N, {"heater_lag": {"time_constant_s": -1.0}})
    p = make_printer(N)
    with pytest.raises(ConfigError, match="unknown experiment"):
        generate(p, "chirp", 100)
    with pytest.raises(ConfigError, match="duration"):
        generate(p, "prbs", 3)
    with pytest.raises(ConfigError, match="needs a printer with the `recoat_cooling`"):
        disturbances(p, 10, jax.random.key(0), recoat=True)
    assert set(EFFECTS) >= {"lateral_conduction", "radiative_loss", "heat_accumulation",
                            "heater_lag", "input_delay", "input_nonlinearity", "recoat_cooling",
                            "ambient_variation"}
    assert isinstance(p.default_disturbance(), PrinterDisturbance)
