"""`minimise(method="lbfgs")`: the quasi-Newton path reaches known optima in tens of
evaluations, is deterministic, keeps the guard's snapshots, and tunes a closed loop."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.control.design import design
from jthermo.errors import ControlError
from jthermo.tune import minimise, tune
from jthermo.tune.lbfgs import direction
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


def _reference_lbfgs(f, x, lr, steps, memory=10, c1=1e-4, c2=0.9, max_evals=10, ftol=1e-9, gtol=1e-8):
    """A plain NumPy L-BFGS from `lbfgs.WolfeLBFGS`'s docstring: the costs of its iterates."""
    def vg(v):
        c, g = f(v)
        return (c if np.isfinite(c) else np.inf), np.where(np.isfinite(g), g, 0.0)

    def two_loop(g, pairs):
        q, alphas = g.copy(), []
        for s, y in reversed(pairs):
            alphas.append((s @ q) / (y @ s))
            q -= alphas[-1] * y
        if pairs:
            q *= (pairs[-1][0] @ pairs[-1][1]) / (pairs[-1][1] @ pairs[-1][1])
        for (s, y), a in zip(pairs, reversed(alphas)):
            q += s * (a - (y @ q) / (y @ s))
        return -q

    fx, g = vg(x)
    costs, pairs = [fx], []
    for _ in range(steps):
        if not np.isfinite(fx) or np.max(np.abs(g)) < gtol:
            break
        d = two_loop(g, pairs)
        if not pairs:
            d *= lr / np.max(np.abs(d))
        lo, hi, alpha, best, slope = 0.0, np.inf, 1.0, None, g @ d
        for _ in range(max_evals):
            ft, gt = vg(x + alpha * d)
            if ft > fx + c1 * alpha * slope:
                hi = alpha
            else:
                best = (x + alpha * d, ft, gt)
                if gt @ d >= c2 * slope:
                    break
                lo = alpha
            alpha = 0.5 * (lo + hi) if np.isfinite(hi) else 2.0 * lo
        if best is None:
            break
        s, y = best[0] - x, best[2] - g
        if s @ y > 1e-12 * np.sqrt((s @ s) * (y @ y)):
            pairs = [*pairs, (s, y)][-memory:]
        done = fx - best[1] <= ftol * max(abs(fx), 1.0)
        x, fx, g = best
        costs.append(fx)
        if done:
            break
    return np.array(costs), x


def _barrier(x):
    """A valley with a wall: not finite where x0 >= 2 (the search must bisect back from it)."""
    c = (x[0] - 1.9) ** 2 + 10.0 * (x[1] - x[0] ** 2) ** 2 - np.log(2.0 - x[0]) if x[0] < 2 else np.inf
    g = np.array([2 * (x[0] - 1.9) - 40.0 * x[0] * (x[1] - x[0] ** 2) + 1 / (2.0 - x[0]),
                  20.0 * (x[1] - x[0] ** 2)]) if x[0] < 2 else np.full(2, np.nan)
    return c, g


def test_lbfgs_iterates_are_a_plain_numpy_lbfgs():
    """Every iterate's cost and the result, against the NumPy reference: a coupled quadratic in
    log space, and a valley whose wall is not finite (the first step runs into it)."""
    res = minimise(_quadratic, START, [jnp.array([2.0, 1.5])], steps=100, method="lbfgs", lr=0.05)
    target = np.array([2.0, 1.5])

    def quad(v):
        g0, o = np.exp(v[:2]), v[2:]
        a, b = g0 - target, o + 1.0
        return float(np.sum(a ** 2 + 3 * b ** 2 + a * b)), np.concatenate([(2 * a + b) * g0, 6 * b + a])

    x0 = np.concatenate([np.log(START.gain), START.offset])
    costs, x = _reference_lbfgs(quad, x0, 0.05, 100)
    np.testing.assert_allclose(np.append(res.history, res.tuned_cost), costs, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(np.log(res.controller.gain), x[:2], atol=1e-9)

    def barrier(c, _):
        x = jnp.concatenate([c.gain, c.offset])
        return jnp.where(x[0] < 2.0, (x[0] - 1.9) ** 2 + 10.0 * (x[1] - x[0] ** 2) ** 2
                         - jnp.log(2.0 - x[0]), jnp.inf)

    start = Toy(jnp.array([-0.5]), jnp.array([0.0]))
    res = minimise(barrier, start, [jnp.zeros(())], steps=60, method="lbfgs", lr=3.0)
    costs, x = _reference_lbfgs(_barrier, np.array([-0.5, 0.0]), 3.0, 60)
    assert len(costs) > 5
    np.testing.assert_allclose(np.append(res.history, res.tuned_cost), costs, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose([res.controller.gain[0], res.controller.offset[0]], x, atol=1e-8)


def test_direction_is_the_bfgs_inverse_update():
    """On f = x'Qx/2 with the exact curvature pairs of the two axes, $-Hg = -Q^{-1} g$; with one
    pair in the newest of two slots, $-Hg$ of the explicit update $H = (I - \\rho s y^\\top)
    \\gamma (I - \\rho y s^\\top) + \\rho s s^\\top$, $\\gamma = s^\\top y / y^\\top y$, $\\rho = 1 / s^\\top y$."""
    Q = np.diag([1.0, 10.0])
    g = Q @ np.array([1.0, 1.0])
    d = direction(jnp.asarray(g), jnp.eye(2), jnp.asarray(Q), 2)
    np.testing.assert_allclose(d, -np.linalg.solve(Q, g), rtol=1e-12)
    s_, y_ = np.array([1.0, 0.3]), np.array([2.0, 0.5])
    rho, gamma, I = 1 / (s_ @ y_), (s_ @ y_) / (y_ @ y_), np.eye(2)
    H = (I - rho * np.outer(s_, y_)) @ (gamma * I) @ (I - rho * np.outer(y_, s_)) + rho * np.outer(s_, s_)
    d = direction(jnp.asarray(g), jnp.asarray([[9.0, 9.0], s_]), jnp.asarray([[7.0, 7.0], y_]), 1)
    np.testing.assert_allclose(d, -H @ g, rtol=1e-12)


def test_lbfgs_finds_the_rosenbrock_minimum():
    """A non-convex valley (Rosenbrock in four variables, the signed leaves): the known
    minimum at ones, by a method that needs curvature pairs to get there in a few hundred
    evaluations (Adam with the same budget does not)."""
    def rosenbrock(c, _):
        x = jnp.concatenate([c.gain, c.offset])
        return jnp.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2)

    start = Toy(jnp.array([-1.2, 1.0]), jnp.array([-1.2, 1.0]))      # signed: not in log space
    res = minimise(rosenbrock, start, [jnp.zeros(())], steps=500, method="lbfgs", lr=0.1)
    np.testing.assert_allclose(np.concatenate([res.controller.gain, res.controller.offset]), 1.0, atol=1e-4)
    assert res.tuned_cost < 1e-8 and res.evaluations < 1000
    adam = minimise(rosenbrock, start, [jnp.zeros(())], steps=res.evaluations, lr=0.1)
    assert adam.tuned_cost > 1e3 * res.tuned_cost


def test_tune_with_lbfgs_lowers_the_closed_loop_cost():
    plant = bed_plant(2, seed=1)
    batch = [[(plant, "custom", _scenarios(plant, seed=0))]]
    start = design("pi_lambda", plant)
    res = tune(start, plant, scenarios=batch, steps=15, guard=False, optimiser="lbfgs")
    assert res.tuned_cost < res.start_cost and res.evaluations <= 15 * 10 + 1
    assert all(np.all(np.asarray(v) > 0) for v in (res.controller.kp, res.controller.ti))
