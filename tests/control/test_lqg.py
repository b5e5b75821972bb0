import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from jthermo.control import design_lqg, solve_dare
from jthermo.control.lqg import lqr_gain
from tests.helpers import central_difference

from .loop import bed_plant


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
