"""`masked_lm(..., budget=...)`: the while loop that reuses the Jacobian after a rejected step
gives the fixed loop's iterates, each problem its own iteration count."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.identify.lm import masked_lm

jax.config.update("jax_enable_x64", True)

T = np.linspace(0.0, 5.0, 60)
#: rate constants far from the start: the early damping trials overshoot (rejected steps)
Y = 2.0 * np.exp(-3.5 * T) + 0.7 * np.exp(-0.4 * T) + 0.01 * np.sin(7.0 * T)


def _residual(p):
    return Y - (p[0] * jnp.exp(-p[1] * T) + p[2] * jnp.exp(-p[3] * T))


P0 = jnp.asarray([0.5, 0.2, 2.0, 0.1])


def test_reuse_gives_the_fixed_iterations_and_rejections_occur():
    mask = jnp.ones(4)
    th_f, _, h_f = masked_lm(_residual, P0, mask, 30)
    th_b, c_b, h_b = masked_lm(_residual, P0, mask, 30, budget=30)
    h_f = np.asarray(h_f)
    assert np.sum(h_f[1:] == h_f[:-1]) >= 2                 # rejected steps: the reuse is exercised
    np.testing.assert_allclose(np.asarray(h_b), h_f, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(th_b), np.asarray(th_f), rtol=1e-9)
    assert float(c_b) == float(np.asarray(h_b)[-1])


def test_budget_stops_each_problem_at_its_count_under_map_and_vmap():
    mask = jnp.asarray([1.0, 1.0, 1.0, 0.0])
    _, _, h_f = masked_lm(_residual, P0, mask, 20)
    h_f = np.asarray(h_f)
    budgets = jnp.asarray([0, 5, 20], jnp.int32)
    run = lambda b: masked_lm(_residual, P0, mask, 20, n_active=3, budget=b)
    mapped = jax.lax.map(run, budgets)
    batched = jax.vmap(run)(budgets)
    for out in (mapped, batched):
        th, _, h = (np.asarray(x) for x in out)
        np.testing.assert_array_equal(th[0], np.asarray(P0))          # budget 0: the start
        np.testing.assert_allclose(h[0], float(np.mean(np.asarray(_residual(P0)) ** 2)), rtol=1e-14)
        np.testing.assert_allclose(h[1, :5], h_f[:5], rtol=1e-12)     # the first 5, then held
        np.testing.assert_array_equal(h[1, 5:], h[1, 4])
        np.testing.assert_allclose(h[2], h_f, rtol=1e-12)
        assert np.all(th[:, 3] == float(P0[3]))                       # masked: never moved
