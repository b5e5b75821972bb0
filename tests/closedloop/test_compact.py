"""The lean cost path (`CompactScenario`) equals the dense path on the expanded scenario."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.closedloop import (
    CompactScenario,
    Events,
    rollout_costs,
    simulate_cost,
)
from jthermo.control.pi import DiagonalPI
from jthermo.errors import ConfigError
from jthermo.models import StateSpace
from jthermo.printer import grid_edges, make_printer

N, T, B = 4, 60, 3


def _model():
    a = np.array([0.93, 0.94, 0.95, 0.92])
    Bm = 0.2 * np.eye(N) + 0.03
    Bw = np.concatenate([np.full((N, 1), 0.01), np.eye(N)], axis=1)   # surroundings + jumps
    return StateSpace(np.diag(a), Bm, np.eye(N), Bw=Bw, u0=np.full(N, 0.5),
                      w0=np.zeros(N + 1), y0=np.full(N, 20.0))


def _scenarios(key=0):
    k = jax.random.split(jax.random.key(key), B)
    t = jnp.array([[5, 20, 20, -1], [0, 59, 30, 7], [10, 11, 12, 13]])
    ch = jnp.array([[1, 2, 3, 1], [4, 4, 1, 2], [1, 1, 2, 3]])
    size = -2.0 * jnp.ones((B, 4))
    return CompactScenario(r0=jnp.full((B, N), 20.0), r1=jnp.full((B, N), 22.0),
                           t_step=jnp.array([0, 10, 30]), w=jnp.tile(jnp.array([1.0, 0, 0, 0, 0]), (B, 1)),
                           events=Events(t, ch, size), y0=jnp.full((B, N), 20.0), key=k,
                           n_samples=T, noise_std=0.05, edges=grid_edges(N))


def test_compact_equals_dense_and_gradients_agree():
    model, sc = _model(), _scenarios()
    pi = DiagonalPI.untuned(N)
    dense = sc.to_scenario()
    assert dense.r.shape == (B, T, N) and dense.d.w.shape == (B, T, N + 1)
    assert float(dense.d.w[0, 20, 2]) == -2.0 and float(dense.d.w[0, 20, 3]) == -2.0

    @eqx.filter_jit
    def both(pi):
        return rollout_costs(model, pi, sc), rollout_costs(model, pi, dense)

    Jc, Jd = both(pi)
    np.testing.assert_allclose(Jc, Jd, rtol=1e-12)
    for u in (1, 3):
        np.testing.assert_allclose(rollout_costs(model, pi, sc, unroll=u), Jd, rtol=1e-12)
    gc, gd = eqx.filter_grad(lambda p: jnp.sum(both(p)[0]))(pi), \
        eqx.filter_grad(lambda p: jnp.sum(both(p)[1]))(pi)
    np.testing.assert_allclose(gc.kp, gd.kp, rtol=1e-10)
    np.testing.assert_allclose(gc.ti, gd.ti, rtol=1e-10)
    # same key -> same cost, other key -> other noise
    J2 = rollout_costs(model, pi, _scenarios(1))
    assert not np.allclose(J2, Jc)
    one = jax.tree.map(lambda a: a[1], sc)
    np.testing.assert_allclose(simulate_cost(model, pi, one), Jc[1], rtol=1e-12)


def test_compact_bad_input():
    with pytest.raises(ConfigError):
        CompactScenario(r0=jnp.zeros(N), r1=jnp.zeros(N), t_step=jnp.array(0), w=jnp.zeros(0),
                        events=Events(jnp.zeros(0, int), jnp.zeros(0, int), jnp.zeros(0)),
                        y0=jnp.zeros(N), n_samples=T, noise_std=0.1)
    sc = CompactScenario(r0=jnp.zeros(N), r1=jnp.zeros(N), t_step=jnp.array(0), w=jnp.zeros(0),
                         events=Events(jnp.zeros(0, int), jnp.zeros(0, int), jnp.zeros(0)),
                         y0=jnp.zeros(N), n_samples=T)
    with pytest.raises(ConfigError):
        simulate_cost(make_printer(N, [], seed=0), DiagonalPI.untuned(N), sc)
