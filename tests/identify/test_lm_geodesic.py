"""`masked_lm(..., geodesic=True)`: the geodesic-acceleration trial reaches the same minimum of a
curved-valley problem in fewer iterations and keeps the early stop's iterates."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.identify.lm import masked_lm

jax.config.update("jax_enable_x64", True)

T = jnp.linspace(0.0, 10.0, 200)
Y = 3.0 * jnp.exp(-T / 4.0) + 0.5 * jnp.exp(-T / 0.7)
TRUE = np.log([3.0, 1 / 4.0, 0.5, 1 / 0.7])
P0 = jnp.asarray([0.0, 0.5, -2.0, -3.0])


def _residual(p):
    """Two decaying exponentials in log parameters (as the diagnosis's log gains and rates)."""
    return Y - (jnp.exp(p[0] - T * jnp.exp(p[1])) + jnp.exp(p[2] - T * jnp.exp(p[3])))


def _iterations_to(hist, level):
    return int(np.argmax(np.asarray(hist) < level)) + 1


def test_geodesic_trial_converges_in_fewer_iterations_to_the_same_minimum():
    mask = jnp.ones(4)
    th_p, _, h_p = masked_lm(_residual, P0, mask, 40)
    th_g, _, h_g = masked_lm(_residual, P0, mask, 40, geodesic=True)
    np.testing.assert_allclose(np.asarray(th_p), TRUE, atol=1e-8)
    np.testing.assert_allclose(np.asarray(th_g), TRUE, atol=1e-8)
    k_p, k_g = _iterations_to(h_p, 1e-20), _iterations_to(h_g, 1e-20)
    assert k_g < k_p, (k_g, k_p)


def test_geodesic_early_stop_keeps_the_fixed_loop_iterates():
    mask = jnp.asarray([1.0, 1.0, 0.0, 1.0])
    th_f, _, h_f = masked_lm(_residual, P0, mask, 25, n_active=3, geodesic=True)
    th_b, _, h_b = masked_lm(_residual, P0, mask, 25, n_active=3, budget=25, geodesic=True)
    np.testing.assert_allclose(np.asarray(th_b), np.asarray(th_f), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(np.asarray(h_b), np.asarray(h_f), rtol=1e-12)
    assert float(th_b[2]) == float(P0[2])
