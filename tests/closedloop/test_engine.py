"""Closed loop: determinism, vmap = loop, gradients against central differences, fitted models."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.closedloop import (
    KINDS,
    Scenario,
    cost,
    make_scenario,
    metrics,
    rollouts,
    run,
    simulate,
    simulate_cost,
)
from jthermo.control.pi import DiagonalPI
from jthermo.errors import ConfigError
from jthermo.models import BedModel
from jthermo.printer import make_printer

N = 4
T = 200


@pytest.fixture(scope="module")
def printer():
    return make_printer(N, ["lateral_conduction", "radiative_loss", "recoat_cooling",
                            "laser_exposure", "sensor_noise"], seed=0)


def test_same_seed_same_run_other_seed_other_run_and_vmap_is_a_loop(printer):
    pi = DiagonalPI.untuned(N)
    a = make_scenario("ensemble", printer, T, 7, n_rollouts=3)
    b = make_scenario("ensemble", printer, T, 7, n_rollouts=3)
    c = make_scenario("ensemble", printer, T, 8, n_rollouts=3)
    assert bool(eqx.tree_equal(a, b))
    assert not np.allclose(a.v, c.v) and not np.allclose(a.d.laser, c.d.laser)
    sim = eqx.filter_jit(rollouts)
    ta, tb, tc = sim(printer, pi, a), sim(printer, pi, b), sim(printer, pi, c)
    np.testing.assert_array_equal(ta.y, tb.y)
    assert not np.allclose(ta.y, tc.y)
    one = eqx.filter_jit(simulate)
    for i in range(2):
        si = jax.tree.map(lambda x: x[i], a)
        np.testing.assert_allclose(one(printer, pi, si).y, ta.y[i], atol=1e-9)
    # the loop keeps inputs in [0, 1] and the bed near its set point
    assert float(ta.u.min()) >= 0.0 and float(ta.u.max()) <= 1.0
    m = metrics(ta, a)
    assert set(m) >= {"mse", "max_neighbour_diff_C", "time_outside_window_s", "overshoot_C",
                      "settling_time_s", "mean_input", "time_to_ready_s"}
    assert all(np.isfinite(v) for v in m.values())
    # measured: 0.58 °C² here (0.56-0.78 over 30 scenario and 5 printer seeds); the loop left
    # open at the steady input gives 2.8, at u = 0.5 4.0. Below 1 °C² (an rms error inside the
    # ±1 °C process window) the PI is doing its job, with a 1.7x margin for numerics.
    assert m["mse"] < 1.0


def test_cost_gradient_matches_central_differences(printer):
    """d cost / d (kp, ti) and d cost / d (a plant parameter), float64, against central FD."""
    sc = make_scenario("print", printer, T, 3)
    base = DiagonalPI(jnp.full(N, 0.05), jnp.full(N, 60.0), 0.5)

    @jax.jit
    def J(theta):
        kp, ti, cap0 = theta[:N], theta[N:2 * N], theta[-1]
        pi = eqx.tree_at(lambda c: (c.kp, c.ti), base, (kp, ti))
        pl = eqx.tree_at(lambda p: p.capacity, printer, printer.capacity.at[0].set(cap0))
        return cost(simulate(pl, pi, sc), sc)

    theta = jnp.concatenate([base.kp, base.ti, printer.capacity[:1]])
    g = jax.grad(J)(theta)
    fd = np.zeros(theta.size)
    for i in range(theta.size):
        h = 1e-6 * max(1.0, abs(float(theta[i])))
        fd[i] = (float(J(theta.at[i].add(h))) - float(J(theta.at[i].add(-h)))) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=2e-4, atol=1e-8)
    assert np.all(np.abs(fd) > 0)
    # the streaming cost (no trajectory kept) is the same number
    np.testing.assert_allclose(simulate_cost(printer, base, sc), J(theta), rtol=1e-12)


def test_fitted_model_plant_equals_printer_by_superposition():
    """A linear printer and its grey-box model under the same scenario: the model gets the
    printer's disturbance response at its output, which is exact for a linear plant."""
    pr = make_printer(N, ["laser_exposure"], seed=1)
    par = pr.linear_bed_parameters()
    model = BedModel.from_physical(*(np.asarray(par[k]) for k in ("capacity", "loss", "gain")),
                                   ts=1.0)
    pi = DiagonalPI(jnp.full(N, 0.05), jnp.full(N, 60.0), 0.5)
    sp = make_scenario("ensemble", pr, T, 4)
    sm = make_scenario("ensemble", model, T, 4, reference=pr)
    np.testing.assert_allclose(sp.r, sm.r)
    tp = simulate(pr, pi, sp)
    tm = simulate(model, pi, sm)
    np.testing.assert_allclose(tm.y, tp.y, atol=1e-8)
    np.testing.assert_allclose(tm.u, tp.u, atol=1e-10)


def test_scenarios_and_run(printer):
    assert set(KINDS) == {"tracking", "powder", "print", "preheat", "ensemble", "load"}
    sc = {k: make_scenario(k, printer, T, 3) for k in ("tracking", "powder", "print", "preheat")}
    for s in sc.values():
        assert isinstance(s, Scenario) and s.r.shape == (T, N) and s.v.shape == (T, N)
    np.testing.assert_allclose(sc["tracking"].r[0] - sc["tracking"].y0, 4.0)
    assert float(sc["powder"].d.recoat.sum()) == 3.0 and float(sc["powder"].d.laser.sum()) == 0.0
    assert float(sc["print"].d.laser.sum()) > 0.0
    np.testing.assert_allclose(sc["preheat"].y0, float(printer.surroundings))
    out = run("ensemble", "untuned", printer, rollouts=3, duration=T, seed=7)
    assert {"scenario", "controller", "zones", "rollouts", "metrics", "seconds"} <= set(out)
    assert out["zones"] == N and out["rollouts"] == 3 and np.isfinite(out["cost"])
    with pytest.raises(ConfigError, match="unknown scenario"):
        make_scenario("warmup", printer, 100, 0)
    with pytest.raises(ConfigError, match="needs a printer with the `recoat_cooling`"):
        make_scenario("powder", make_printer(N), 100, 0)
    with pytest.raises(ConfigError, match="unknown weight"):
        cost(simulate(printer, DiagonalPI.untuned(N), sc["print"]), sc["print"], {"speed": 1.0})
    with pytest.raises(ConfigError, match="drives 3 zones"):
        run("tracking", DiagonalPI.untuned(3), printer, rollouts=1, duration=50)
    # a controller tuned at another sample time is refused (it ran silently at the plant's)
    with pytest.raises(ConfigError, match="sample time of 2 s, the plant at 1 s"):
        run("tracking", DiagonalPI.untuned(N, ts=2.0), printer, rollouts=1, duration=50)
