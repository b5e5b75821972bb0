import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from jthermo.control import design_lqg, solve_dare
from jthermo.control.lqg import lqr_gain
from tests.helpers import central_difference

from .loop import bed_plant, closed_loop, step_reference


def _random_system(seed, n=4, m=2):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A = 1.05 * A / np.max(np.abs(np.linalg.eigvals(A)))      # slightly unstable: DARE must stabilise
    B = rng.normal(size=(n, m))
    Q = np.diag(rng.uniform(0.5, 2.0, n))
    R = np.diag(rng.uniform(0.5, 2.0, m))
    return A, B, Q, R


@pytest.mark.parametrize("seed", [0, 1])
def test_riccati_matches_scipy(seed):
    A, B, Q, R = _random_system(seed)
    X = np.asarray(solve_dare(jnp.asarray(A), jnp.asarray(B), jnp.asarray(Q), jnp.asarray(R)))
    X_ref = scipy.linalg.solve_discrete_are(A, B, Q, R)
    np.testing.assert_allclose(X, X_ref, rtol=1e-9, atol=1e-9)
    L, _ = lqr_gain(jnp.asarray(A), jnp.asarray(B), jnp.asarray(Q), jnp.asarray(R))
    assert np.max(np.abs(np.linalg.eigvals(A - B @ np.asarray(L)))) < 1.0


def test_riccati_gradient_matches_finite_differences():
    A, B, _, _ = _random_system(2, n=3, m=2)
    A, B = jnp.asarray(A), jnp.asarray(B)

    def f(logq):
        X = solve_dare(A, B, jnp.diag(jnp.exp(logq[:3])), jnp.diag(jnp.exp(logq[3:])))
        return jnp.sum(X * jnp.arange(1.0, 10.0).reshape(3, 3))

    z = jnp.asarray(np.log([1.0, 2.0, 0.5, 1.5, 0.7]))
    g = jax.grad(f)(z)
    g_fd = central_difference(jax.jit(f), z)
    np.testing.assert_allclose(g, g_fd, rtol=1e-6, atol=1e-7)


def test_lqg_gains_and_static_gain():
    plant = bed_plant(3)
    c = design_lqg(plant, Q1=2.0, Q2=0.5, Qi=0.05)
    g = c.gains()
    A, B, C = (np.asarray(m) for m in (plant.A, plant.B, plant.C))
    # closed loop with the integrators is stable
    Aa = np.block([[A, np.zeros((3, 3))], [-C, np.eye(3)]])
    Ba = np.vstack([B, np.zeros((3, 3))])
    La = np.hstack([np.asarray(g.Lx), np.asarray(g.Li)])
    assert np.max(np.abs(np.linalg.eigvals(Aa - Ba @ La))) < 1.0
    # the gains agree with scipy's DARE on the same augmented problem
    Qa = scipy.linalg.block_diag(C.T @ (2.0 * C) + 1e-9 * np.eye(3), 0.05 * np.eye(3))
    X = scipy.linalg.solve_discrete_are(Aa, Ba, Qa, 0.5 * np.eye(3))
    L_ref = np.linalg.solve(0.5 * np.eye(3) + Ba.T @ X @ Ba, Ba.T @ X @ Aa)
    np.testing.assert_allclose(La, L_ref, rtol=1e-7, atol=1e-9)
    # L0 gives unit static gain of the state-feedback loop
    Gcl = C @ np.linalg.solve(np.eye(3) - A + B @ np.asarray(g.Lx), B) @ np.asarray(g.L0)
    np.testing.assert_allclose(Gcl, np.eye(3), atol=1e-9)
    # the observer is stable
    M = np.asarray(g.M)
    assert np.max(np.abs(np.linalg.eigvals(A - A @ M @ C))) < 1.0


def _classical_loop(c, plant, r):
    """The LQG law without the set-point weights, in NumPy from the design's gains."""
    g = c.gains()
    Lx, Li, L0, M = (np.asarray(m) for m in (g.Lx, g.Li, g.L0, g.M))
    A, B, C = (np.asarray(m) for m in (c.A, c.B, c.C))
    u_op, y_op = np.asarray(c.u_op), np.asarray(c.y_op)
    xp = np.asarray(plant.initial_state(plant.y0))
    y = np.asarray(plant.output(xp))
    x = np.linalg.solve(np.eye(A.shape[0]) - A + B @ Lx, B @ (L0 @ (y - y_op)))
    xi, us = np.zeros_like(y), []
    for rk in np.asarray(r):
        y = np.asarray(plant.output(xp))
        x_f = x + M @ (y - y_op - C @ x)
        u_req = u_op + L0 @ (rk - y_op) - Lx @ x_f - Li @ xi
        u = np.clip(u_req, 0.0, 1.0)
        e = rk - y
        hold = ((u_req > 1.0) & (e > 0)) | ((u_req < 0.0) & (e < 0))
        xi = np.where(hold, xi, xi + c.ts * e)
        x = A @ x_f + B @ (u - u_op)
        xp = np.asarray(plant.step(jnp.asarray(xp), jnp.asarray(u)))
        us.append(u)
    return np.asarray(us)


@pytest.mark.parametrize("size", [0.5, 6.0])          # linear, and saturated during the rise
def test_setpoint_weights_start_at_the_classical_design(size):
    plant = bed_plant(2, seed=3)
    c = design_lqg(plant, Q1=2.0, Q2=0.5, Qi=0.05)
    assert np.all(np.asarray(c.b0) == 0.0)
    r = step_reference(plant, 80, size, at=5)
    _, us = closed_loop(c, plant, r)
    np.testing.assert_allclose(us, _classical_loop(c, plant, r), rtol=1e-10, atol=1e-12)
    # with a zero weight the reference model's time constant has no effect
    _, us2 = closed_loop(eqx.tree_at(lambda k: k.tau_r, c, 3.0 * c.tau_r), plant, r)
    np.testing.assert_array_equal(np.asarray(us2), np.asarray(us))
    if size > 1.0:
        assert np.mean(np.asarray(us) == 1.0) > 0.05        # the anti-windup path is exercised


def test_setpoint_weights_gradient_matches_central_differences():
    plant = bed_plant(2, seed=3)
    c0 = design_lqg(plant, Q1=2.0, Q2=0.5, Qi=0.05)
    r = step_reference(plant, 60, 0.3, at=5)
    d = jnp.zeros((60, 2)).at[40, 0].set(-0.2)

    def cost(theta):
        c = eqx.tree_at(lambda k: (k.b0, k.tau_r), c0, (theta[0:2], jnp.exp(theta[2:4])))
        ys, us = closed_loop(c, plant, r, d)
        return jnp.mean((ys - r) ** 2) + 0.1 * jnp.mean((us - plant.u0) ** 2)

    f = jax.jit(cost)
    for theta in (np.r_[0.0, 0.0, np.log(np.asarray(c0.tau_r))],              # the start
                  np.array([0.3, -0.2, np.log(5.0), np.log(12.0)])):
        g = np.asarray(jax.grad(f)(jnp.asarray(theta)))
        np.testing.assert_allclose(g, central_difference(f, theta), rtol=1e-5, atol=1e-10)
        assert np.all(g[:2] != 0.0)                          # the weight moves the cost
