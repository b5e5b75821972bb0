import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.control import DecoupledPI
from jthermo.errors import ControlError
from jthermo.tune import minimise
from tests.control.loop import bed_plant, closed_loop, step_reference
from tests.helpers import central_difference

T, B = 60, 4


@pytest.fixture(scope="module")
def problem():
    plant = bed_plant(2, seed=1)
    r = step_reference(plant, T, 0.5, at=3)
    key = jax.random.key(0)
    d = -0.3 * (jax.random.uniform(key, (B, T, 2)) < 0.03)     # random cold-layer drops

    def loss(ctrl, dist):
        ys, us = jax.vmap(lambda dd: closed_loop(ctrl, plant, r, dd))(dist)
        return jnp.mean((ys - r[None]) ** 2) + 0.01 * jnp.mean((us - plant.u0) ** 2)

    start = DecoupledPI(jnp.array([0.05, 0.05]), jnp.array([80.0, 80.0]), plant.u0, ts=1.0)
    return plant, loss, d, start


def test_tuning_lowers_cost_and_keeps_gains_valid(problem):
    plant, loss, d, start = problem
    seen = []
    res = minimise(loss, start, [d], steps=30, lr=0.1, progress=lambda i, c: seen.append(c))
    assert len(seen) == 30 and res.history.shape == (30,)
    assert res.tuned_cost < 0.7 * res.start_cost
    assert float(loss(res.controller, d)) == pytest.approx(res.tuned_cost, rel=1e-9)
    assert np.all(np.asarray(res.controller.kp) > 0) and np.all(np.asarray(res.controller.ti) > 0)
    # the tuned loop is stable: a long simulation settles
    ys, _ = closed_loop(res.controller, plant, step_reference(plant, 400, 0.5))
    assert np.all(np.isfinite(ys)) and np.max(np.abs(ys[-1] - plant.y0 - 0.5)) < 1e-2


def test_tuning_gradient_matches_finite_differences(problem):
    _, loss, d, start = problem
    params, static = eqx.partition(start, eqx.is_inexact_array)
    from jax.flatten_util import ravel_pytree
    flat, unravel = ravel_pytree(params)
    f = jax.jit(lambda th: loss(eqx.combine(unravel(th), static), d))
    np.testing.assert_allclose(jax.grad(f)(flat), central_difference(f, flat), rtol=1e-5,
                               atol=1e-9)


def test_never_returns_nan(problem):
    _, loss, d, start = problem

    def fragile(ctrl, dist):      # a cost that turns NaN when a gain leaves a safe range
        c = loss(ctrl, dist)
        return jnp.where(jnp.max(ctrl.kp) > 0.2, jnp.nan, c)

    res = minimise(fragile, start, [d], steps=40, lr=0.3)
    assert np.isfinite(res.tuned_cost) and res.tuned_cost <= res.start_cost
    assert np.all(np.asarray(res.controller.kp) <= 0.2)


def test_errors(problem):
    _, loss, d, start = problem
    with pytest.raises(ControlError, match="steps must be"):
        minimise(loss, start, [d], steps=-1)
    with pytest.raises(ControlError, match="non-finite cost"):
        minimise(lambda c, b: jnp.nan * loss(c, b), start, [d], steps=1)


@pytest.mark.slow
def test_tune_report_on_a_small_printer():
    from jthermo.tune import tune_report

    rep = tune_report("pi_lambda", zones=2, rollouts=2, steps=4, duration=120.0, seed=3)
    ctrl = rep.pop("tuned")
    assert set(rep) >= {"controller", "start_cost", "tuned_cost", "lambda_pi_cost",
                        "improvement_percent", "scenarios", "seconds"}
    assert set(rep["scenarios"]) == {"tracking", "powder", "print"}
    assert np.isfinite(rep["tuned_cost"]) and np.all(np.asarray(ctrl.kp) > 0)
    assert rep["train_tuned_cost"] <= rep["train_start_cost"]
