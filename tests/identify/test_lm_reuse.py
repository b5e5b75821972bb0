"""`masked_lm` (the optimistix solver `MaskedLM`): its iterates are those of a plain NumPy
Levenberg–Marquardt written from the docstring's rules (the Jacobian recomputed every iteration,
so the reuse after a rejected step is checked too), and a budget stops each problem at its count."""

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


def _reference(p, free, n_iter):
    """Marquardt's rules in NumPy: the analytic Jacobian, three damping trials, the best kept."""
    p, lam = np.array(p, float), 1e-2
    r = np.asarray(_residual(p))
    cost, hist = np.mean(r ** 2), []
    for _ in range(n_iter):
        e1, e3 = np.exp(-p[1] * T), np.exp(-p[3] * T)
        J = -np.stack([e1, -p[0] * T * e1, e3, -p[2] * T * e3], axis=1)[:, free]
        H, g = J.T @ J, J.T @ r
        d = np.diag(H) + 1e-9 * (np.max(np.diag(H)) + 1e-30)
        trials = []
        for lm in lam * np.array([0.1, 1.0, 10.0]):
            q = p.copy()
            q[free] += np.clip(-np.linalg.solve(H + lm * np.diag(d), g), -2.0, 2.0)
            trials.append((np.mean(np.asarray(_residual(q)) ** 2), lm, q))
        c, lm, q = min(trials, key=lambda x: x[0])
        if c < cost:
            p, cost, lam = q, c, np.clip(0.5 * lm, 1e-9, 1e9)
            r = np.asarray(_residual(p))
        else:
            lam = np.clip(30.0 * lam, 1e-9, 1e9)
        hist.append(cost)
    return p, np.array(hist)


def test_iterates_are_the_plain_algorithm_and_rejections_occur():
    for free in ([0, 1, 2, 3], [0, 1, 2]):
        mask = jnp.zeros(4).at[jnp.asarray(free)].set(1.0)
        th_ref, h_ref = _reference(P0, free, 30)
        assert np.sum(h_ref[1:] == h_ref[:-1]) >= 2             # rejected steps: the reuse is exercised
        for kw in ({}, {"budget": 30}, {"n_active": len(free)}):
            th, c, h = masked_lm(_residual, P0, mask, 30, **kw)
            np.testing.assert_allclose(np.asarray(h), h_ref, rtol=1e-9)
            np.testing.assert_allclose(np.asarray(th), th_ref, rtol=1e-7)
            assert float(c) == float(np.asarray(h)[-1])


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
