"""`mechanisms.zoh_blocks` on the m × m blocks: equal to the exact hold (scipy's exponential of the
block matrix) and to the same Taylor series on the dense 2m × 2m matrix it replaced
(`benchmarks.common.zoh_dense`, the reference the joint fit's benchmark times too); its
forward-mode derivative against central differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm

import jthermo.diagnose.mechanisms as M
from benchmarks.common import taylor_expm, zoh_dense

jax.config.update("jax_enable_x64", True)


def _rates(m, seed):
    """A stable rate matrix like the diagnosis models' (loss on the diagonal, weak coupling)."""
    rng = np.random.default_rng(seed)
    return -np.diag(0.002 + 0.3 * rng.random(m)) + 0.01 * rng.random((m, m)) * (1 - np.eye(m))


def test_expm_matches_scipy():
    rng = np.random.default_rng(2)
    for scale in (0.01, 1.0, 20.0):
        A = scale * rng.normal(size=(6, 6)) - scale * 3 * np.eye(6)
        np.testing.assert_allclose(np.asarray(taylor_expm(jnp.asarray(A))), expm(A),
                                   rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("m, ts", [(3, 1.0), (12, 1.0), (6, 5.0)])
def test_zoh_blocks_match_exact_hold_and_dense_series(m, ts):
    A = _rates(m, m)
    Bc = np.random.default_rng(1).standard_normal((m, 4))
    E, Bd, P1 = M.zoh_blocks(jnp.asarray(A), jnp.asarray(Bc), ts)
    F = expm(np.block([[A, np.eye(m)], [np.zeros((m, 2 * m))]]) * ts)
    np.testing.assert_allclose(E, F[:m, :m], rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(P1, F[:m, m:], rtol=1e-12, atol=1e-13 * ts)
    np.testing.assert_allclose(Bd, F[:m, m:] @ Bc, rtol=1e-11, atol=1e-12 * ts)
    for x, y in zip((E, Bd, P1), zoh_dense(jnp.asarray(A), jnp.asarray(Bc), ts)):
        np.testing.assert_allclose(x, y, rtol=1e-13, atol=1e-14 * float(jnp.abs(y).max()))


def test_zoh_jvp_matches_central_differences_and_dense_series():
    m = 5
    A, Bc = jnp.asarray(_rates(m, 7)), jnp.asarray(np.random.default_rng(2).standard_normal((m, 3)))
    rng = np.random.default_rng(3)
    dA, dB = jnp.asarray(0.01 * rng.standard_normal((m, m))), jnp.asarray(rng.standard_normal((m, 3)))
    f = lambda A, B: M.zoh_blocks(A, B, 2.0)
    _, d = jax.jvp(f, (A, Bc), (dA, dB))
    h = 1e-4
    plus, minus = f(A + h * dA, Bc + h * dB), f(A - h * dA, Bc - h * dB)
    for di, p, q in zip(d, plus, minus):
        np.testing.assert_allclose(di, (p - q) / (2 * h), rtol=1e-6, atol=1e-9)
    _, d2 = jax.jvp(lambda A, B: zoh_dense(A, B, 2.0), (A, Bc), (dA, dB))
    for x, y in zip(d, d2):
        np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-14 * float(jnp.abs(y).max()))
