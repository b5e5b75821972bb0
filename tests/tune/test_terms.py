"""The lean path's cost terms (`tune.terms`): each term against a NumPy reference on the dense
trajectory, the overshoot term's gradient against central differences, and weights
normalised by each term's scale."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from jthermo.closedloop import ModelDisturbance, Scenario, cost, rollouts
from jthermo.control import DiagonalPI
from jthermo.errors import ControlError
from jthermo.models import StateSpace
from jthermo.tune.terms import (
    OVERSHOOT_MARGIN,
    TERMS,
    batch_parts,
    normalised_weights,
    simulate_parts,
    simulate_terms,
)
from tests.helpers import central_difference

S = 0.1      # the terms' default smoothing, °C


def _rollout(tree, b):
    """Rollout `b` of a batched scenario or trajectory."""
    return jax.tree.map(lambda a: a[b], tree)


def _plant():
    """One heater, one sensor: first order (pole 0.95), 40 °C per unit input above 20 °C."""
    return StateSpace(jnp.array([[0.95]]), jnp.array([[2.0]]), jnp.array([[1.0]]),
                      u0=jnp.array([0.0]), y0=jnp.array([20.0]))


def _changes(T=120, B=2):
    """Settled at 40 °C, up 5 °C at sample 20, down 10 °C at sample 70; measurement noise."""
    k = jnp.arange(T)[:, None]
    r = 40.0 + 5.0 * (k >= 20) - 10.0 * (k >= 70)
    v = 0.02 * jax.random.normal(jax.random.key(3), (B, T, 1))
    return Scenario(r=jnp.broadcast_to(r, (B, T, 1)).astype(jnp.float64),
                    d=ModelDisturbance(w=jnp.zeros((B, T, 0)), dy=jnp.zeros((B, T, 1))),
                    v=v, y0=jnp.full((B, 1), 40.0), kind="custom", ts=1.0)


def _pi(kp=0.05, ti=1.0):
    return DiagonalPI(jnp.array([kp]), jnp.array([ti]), jnp.array([0.5]))


def _reference_parts(traj, sc, window):
    """The terms in NumPy from the dense trajectory of one rollout."""
    T, r, u = (np.asarray(a, np.float64) for a in (traj.temperature, traj.r, traj.u))
    e = T - r
    d = np.zeros_like(r)
    last = np.sign(r[0] - np.asarray(sc.y0))
    prev = r[0]
    for k in range(r.shape[0]):
        moved = np.abs(r[k] - prev) > 1e-9
        last = np.where(moved, np.sign(r[k] - prev), last)
        d[k], prev = last, r[k]
    o = np.abs(d) * S * np.logaddexp(0.0, (d * e - OVERSHOOT_MARGIN * S) / S)
    win = 1.0 / (1.0 + np.exp(-(np.sqrt(e ** 2 + (0.1 * S) ** 2) - window) / S))
    return np.array([np.mean(e ** 2), 0.0, np.mean(np.diff(u, axis=0) ** 2), np.mean(win),
                     np.mean(o ** 2), np.mean((np.asarray(traj.y) - r) ** 2)])


def test_parts_match_a_numpy_reference_on_the_dense_trajectory():
    plant, sc, c = _plant(), _changes(), _pi()
    traj = rollouts(plant, c, sc)
    for b in range(2):
        one, tr = _rollout(sc, b), _rollout(traj, b)
        ref = _reference_parts(tr, one, one.window)
        got = np.asarray(simulate_parts(plant, c, one))
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-14)
    assert ref[4] > 1e-3            # this PI overshoots both changes: the term is not idle
    # the weighted sum: equal to closedloop.cost without overshoot, plus w * term with it
    J0 = np.mean([float(simulate_terms(plant, c, _rollout(sc, b))[0]) for b in range(2)])
    np.testing.assert_allclose(J0, float(cost(traj, sc)), rtol=1e-12)
    one = _rollout(sc, 0)
    parts = np.asarray(simulate_parts(plant, c, one))
    J = float(simulate_terms(plant, c, one, {"overshoot": 2.5, "effort": 7.0})[0])
    np.testing.assert_allclose(J, parts[0] + 7.0 * parts[2] + parts[3] + 2.5 * parts[4],
                               rtol=1e-12)


def test_overshoot_is_zero_without_a_setpoint_change_and_falls_with_a_gentler_loop():
    plant = _plant()
    sc = _changes()
    flat = eqx.tree_at(lambda s: s.r, sc, jnp.full_like(sc.r, 40.0))
    assert float(np.max(np.asarray(batch_parts(_pi(), [(plant, "custom", flat)]))[:, 4])) == 0.0
    hot = np.asarray(batch_parts(_pi(0.05, 1.0), [(plant, "custom", sc)]))[0, 4]
    calm = np.asarray(batch_parts(_pi(0.05, 30.0), [(plant, "custom", sc)]))[0, 4]
    assert calm < 0.1 * hot


def test_overshoot_term_gradient_matches_central_differences():
    plant, sc = _plant(), _changes()
    params, static = eqx.partition(_pi(), eqx.is_inexact_array)
    flat, unravel = ravel_pytree(params)
    f = jax.jit(lambda th: jnp.mean(jax.vmap(lambda s: simulate_parts(
        plant, eqx.combine(unravel(th), static), s)[4])(sc)))
    g = np.asarray(jax.grad(f)(flat))
    free = np.flatnonzero(np.abs(g) > 0)
    assert free.size >= 2                              # kp and ti at least
    fd = central_difference(lambda th: f(jnp.asarray(flat).at[free].set(th)),
                            np.asarray(flat)[free])
    np.testing.assert_allclose(g[free], fd, rtol=1e-5, atol=1e-10)


def test_normalised_weights_put_each_term_at_its_weight():
    plant, sc, c = _plant(), _changes(), _pi()
    parts = np.mean(np.asarray(batch_parts(c, [(plant, "custom", sc)])), axis=0)
    scales = {k: float(parts[i]) for i, k in enumerate(TERMS)}
    weights = {"tracking": 1.0, "effort": 0.5, "window": 0.25, "overshoot": 3.0}
    w = normalised_weights(weights, scales)
    # at the scales' controller each term contributes exactly its weight
    one = _rollout(sc, 0)
    p = np.asarray(simulate_parts(plant, c, one))
    for i, k in enumerate(TERMS):
        if k in weights:
            assert w[k] * scales[k] == pytest.approx(weights[k])
    assert w["uniformity"] == 1.0                       # zero scale: weight as given
    J = float(simulate_terms(plant, c, one, w)[0])
    np.testing.assert_allclose(J, sum(w[k] * p[i] for i, k in enumerate(TERMS)
                                      if k != "uniformity"), rtol=1e-12)
    with pytest.raises(ControlError, match="unknown cost term `speed`"):
        normalised_weights(weights, {"speed": 1.0})
    with pytest.raises(ControlError, match="unknown cost weight `speed`"):
        normalised_weights({"speed": 1.0}, scales)
