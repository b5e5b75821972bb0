"""The early-stopped masked Levenberg–Marquardt (`masked_lm(..., rtol=...)`) keeps its answers."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.identify.lm import STALL, masked_lm

jax.config.update("jax_enable_x64", True)

T = np.linspace(0.0, 5.0, 60)


def _residual(p, y):
    """Two decaying exponentials: a small smooth problem with a curved valley."""
    return y - (p[0] * jnp.exp(-p[1] * T) + p[2] * jnp.exp(-0.2 * T))


def _data(p):
    return np.asarray(-_residual(jnp.asarray(p, float), jnp.zeros(T.size)))


def test_early_stop_reaches_the_fixed_iteration_minimum_sooner():
    y = jnp.asarray(_data([2.0, 1.5, 0.7]))
    p0 = jnp.asarray([1.0, 0.5, 0.0])
    mask = jnp.ones(3)
    th_f, c_f, h_f = masked_lm(lambda p: _residual(p, y), p0, mask, 40)
    th_e, c_e, h_e = masked_lm(lambda p: _residual(p, y), p0, mask, 40, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(th_e), [2.0, 1.5, 0.7], rtol=1e-5)
    np.testing.assert_allclose(np.asarray(th_e), np.asarray(th_f), rtol=1e-5)
    h_e = np.asarray(h_e)
    used = int(np.argmax(h_e == h_e[-1])) + 1            # first iteration at the final cost
    assert STALL < used < 40
    assert np.all(h_e[used - 1:] == float(c_e))          # the final cost repeated after the stop
    np.testing.assert_array_equal(h_e[:used], np.asarray(h_f)[:used])   # same iterations until then


def test_early_stop_under_vmap_keeps_each_problem_its_own():
    """Problems that stop at different iterations get what each gets alone (stopped ones frozen)."""
    ys = jnp.asarray(np.stack([_data([2.0, 1.5, 0.7]), _data([0.3, 4.0, 2.0])]))
    p0 = jnp.asarray([[1.0, 0.5, 0.0], [1.0, 0.5, 0.0]])
    masks = jnp.asarray([[1.0, 1.0, 1.0], [1.0, 0.0, 1.0]])          # the second: rate fixed
    run = lambda p, m, y: masked_lm(lambda q: _residual(q, y), p, m, 40, rtol=1e-6)
    th_v, c_v, h_v = jax.vmap(run)(p0, masks, ys)
    for j in range(2):
        th_j, c_j, h_j = run(p0[j], masks[j], ys[j])
        # batched and single linear solves round differently (1e-9 on the second problem's
        # flat optimum on some CPUs); a problem iterated past its own stop would move further
        np.testing.assert_allclose(np.asarray(th_v[j]), np.asarray(th_j), rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(np.asarray(h_v[j]), np.asarray(h_j), rtol=1e-9, atol=1e-18)
    assert float(th_v[1, 1]) == 0.5                                   # masked: never moved

