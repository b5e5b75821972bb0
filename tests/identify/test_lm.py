"""The masked Levenberg–Marquardt solver (`jthermo.identify.lm.masked_lm`)."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.identify.lm import masked_lm


def _linear_problem(seed=0, m=30, p=5):
    rng = np.random.default_rng(seed)
    return jnp.asarray(rng.standard_normal((m, p))), jnp.asarray(rng.standard_normal(m))


def test_free_parameters_reach_the_least_squares_solution_and_fixed_ones_stay():
    A, b = _linear_problem()
    theta0 = jnp.asarray([0.3, -0.2, 0.1, 0.5, -0.4])
    mask = jnp.asarray([1.0, 0.0, 1.0, 1.0, 0.0])
    theta, cost, hist = masked_lm(lambda th: A @ th - b, theta0, mask, 30)
    free = np.flatnonzero(np.asarray(mask))
    fixed = np.flatnonzero(np.asarray(mask) == 0)
    # least squares over the free parameters with the fixed ones at their start values
    rhs = np.asarray(b) - np.asarray(A)[:, fixed] @ np.asarray(theta0)[fixed]
    ref = np.linalg.lstsq(np.asarray(A)[:, free], rhs, rcond=None)[0]
    np.testing.assert_array_equal(np.asarray(theta)[fixed], np.asarray(theta0)[fixed])
    np.testing.assert_allclose(np.asarray(theta)[free], ref, rtol=1e-8, atol=1e-10)
    assert hist.shape == (30,) and np.all(np.diff(np.asarray(hist)) <= 0)
    assert float(cost) == float(hist[-1])
    np.testing.assert_allclose(float(cost), np.mean((np.asarray(A @ theta - b)) ** 2), rtol=1e-12)


def test_vmapped_masks_equal_single_solves_and_n_active_bounds_the_columns():
    A, b = _linear_problem(1)
    res = lambda th: jnp.tanh(A @ th) - 0.5 * b      # noqa: E731
    theta0 = jnp.full((3, 5), 0.1)
    masks = jnp.asarray([[1.0, 1, 0, 0, 0], [0, 0, 1, 1, 0], [1, 0, 1, 0, 1]])
    batched = jax.vmap(lambda t, m: masked_lm(res, t, m, 15, n_active=3))(theta0, masks)
    for k in range(3):
        # one solve without the bound (5 Jacobian columns, not 3): equal up to rounding (batched
        # and single solves round differently: 1.0e-8 relative after 15 iterations on some CPUs)
        single = masked_lm(res, theta0[k], masks[k], 15)
        for a, s in zip(batched, single):
            np.testing.assert_allclose(np.asarray(a[k]), np.asarray(s), rtol=1e-7, atol=1e-12)
        np.testing.assert_array_equal(np.asarray(batched[0][k])[np.asarray(masks[k]) == 0], 0.1)


def test_damped_systems_are_factored_one_matrix_at_a_time():
    """Every LAPACK call of the solver takes one matrix (`num_batch_dims = 0`): a batched LU of
    the three damped systems deals them to XLA's CPU thread pool and blocks a pool thread on
    them, and two such programs running at once on two cores waited for each other for good."""
    A, b = _linear_problem(2, m=120, p=70)       # 3 x 70^3 LU flops: over jaxlib's threshold
    solve = jax.jit(lambda th, m: masked_lm(lambda t: A @ t - b, th, m, 3, rtol=1e-10))
    text = solve.lower(jnp.zeros(70), jnp.ones(70)).as_text()
    calls = [ln for ln in text.splitlines() if "custom_call @lapack_" in ln]
    assert any("getrf" in ln for ln in calls)
    for ln in calls:
        assert 'num_batch_dims = "0"' in ln, ln
