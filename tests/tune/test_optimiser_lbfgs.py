"""`minimise(method="lbfgs")`: the quasi-Newton path reaches known optima in tens of
evaluations, is deterministic, keeps the guard's snapshots, and tunes a closed loop."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.control.design import design
from jthermo.errors import ControlError
from jthermo.tune import minimise, tune
from jthermo.tune.optimiser import lbfgs_direction, wolfe_search
from tests.control.loop import bed_plant
from tests.tune.test_optimiser import _scenarios


class Toy(eqx.Module):
    gain: jnp.ndarray      # positive: tuned in log space
    offset: jnp.ndarray    # signed: tuned as it is


def _quadratic(c, target):
    """A coupled quadratic in (gain, offset) with its minimum at gain = target, offset = -1."""
    a, b = c.gain - target, c.offset + 1.0
    return jnp.sum(a ** 2 + 3.0 * b ** 2 + a * b)


START = Toy(jnp.array([0.5, 4.0]), jnp.array([2.0, -3.0]))


def test_lbfgs_reaches_the_optimum_in_tens_of_evaluations():
    res = minimise(_quadratic, START, [jnp.array([2.0, 1.5])], steps=100, method="lbfgs")
    np.testing.assert_allclose(res.controller.gain, [2.0, 1.5], atol=1e-5)
    np.testing.assert_allclose(res.controller.offset, [-1.0, -1.0], atol=1e-5)
    assert res.tuned_cost < 1e-9 and res.evaluations <= 40 and res.method == "lbfgs"
    # Adam with the same budget of gradient evaluations is still far from it
    adam = minimise(_quadratic, START, [jnp.array([2.0, 1.5])], steps=res.evaluations)
    assert adam.tuned_cost > 1e3 * res.tuned_cost


def test_lbfgs_minimises_the_mean_over_batches():
    """With several batches L-BFGS minimises their mean: targets 1 and 3 give gain 2."""
    res = minimise(_quadratic, START, [jnp.array([1.0, 1.0]), jnp.array([3.0, 3.0])],
                   steps=100, method="lbfgs")
    np.testing.assert_allclose(res.controller.gain, [2.0, 2.0], atol=1e-5)


def test_lbfgs_is_deterministic_and_keeps_snapshots():
    runs = [minimise(_quadratic, START, [jnp.array([2.0, 1.5])], steps=100, snapshots=4,
                     method="lbfgs") for _ in range(2)]
    np.testing.assert_array_equal(runs[0].history, runs[1].history)
    np.testing.assert_array_equal(runs[0].controller.gain, runs[1].controller.gain)
    snaps = runs[0].snapshots
    assert snaps[0][0] == 0 and np.isclose(snaps[0][1], runs[0].start_cost)
    # the best iterate is a candidate
    assert any(np.array_equal(c.gain, runs[0].controller.gain) for _, _, c in snaps)
    assert runs[0].history[0] == runs[0].start_cost
    with pytest.raises(ControlError, match="unknown optimiser"):
        minimise(_quadratic, START, [jnp.array([2.0, 1.5])], method="sgd")


def test_wolfe_search_and_direction():
    """On f = x'Qx/2 the step returned meets both Wolfe conditions, and with the exact
    curvature pairs of the two axes the direction is the Newton step."""
    Q = np.diag([1.0, 10.0])

    def vg(x):
        return 0.5 * float(x @ Q @ x), Q @ x

    x0 = np.array([1.0, 1.0])
    f0, g0 = vg(x0)
    d = -g0
    x, f, g, n = wolfe_search(vg, x0, f0, g0, d)
    assert f <= f0 + 1e-4 * (x - x0) @ g0 and g @ d >= 0.9 * (g0 @ d) and n <= 10
    pairs = [(np.array([1.0, 0.0]), np.array([1.0, 0.0])),
             (np.array([0.0, 1.0]), np.array([0.0, 10.0]))]
    np.testing.assert_allclose(lbfgs_direction(g0, pairs), -np.linalg.solve(Q, g0))


def test_tune_with_lbfgs_lowers_the_closed_loop_cost():
    plant = bed_plant(2, seed=1)
    batch = [[(plant, "custom", _scenarios(plant, seed=0))]]
    start = design("pi_lambda", plant)
    res = tune(start, plant, scenarios=batch, steps=15, guard=False, optimiser="lbfgs")
    assert res.tuned_cost < res.start_cost and res.evaluations <= 15 * 10 + 1
    assert all(np.all(np.asarray(v) > 0) for v in (res.controller.kp, res.controller.ti))
