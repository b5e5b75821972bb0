"""Record lengths padded to buckets: criterion, gradient and solve unchanged; programs shared."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo import runtime
from jthermo.identify import matrix_free, padding, pem
from jthermo.identify.statespace import diagonal_residual


def _oe_residual(theta, args):
    """First-order output error y - b/(1 - a q^-1) u (a causal simulation), (T, 1)."""
    y, u = args
    a, b = theta[0], theta[1:]

    def body(x, uk):
        return a * x + uk @ b, x

    _, xs = jax.lax.scan(body, jnp.zeros((), theta.dtype), u)
    return (y - xs)[:, None]


def _record(T, nu=2, seed=0):
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.0, 1.0, (T, nu))
    x, y = 0.0, np.empty(T)
    b = np.linspace(0.2, 0.4, nu)
    for t in range(T):
        y[t] = x
        x = 0.9 * x + u[t] @ b
    return y + 0.01 * rng.standard_normal(T), u


@pytest.mark.parametrize("T", [1, 7, 8, 9, 63, 600, 637, 1000, 3600])
def test_bucket_bounds(T):
    b = padding.bucket(T)
    assert T <= b <= max(T, int(np.ceil(1.25 * T)))
    assert padding.bucket(b) == b


def test_buckets_are_few():
    # lengths 600 .. 11_700 s in 37 s steps (the long-lived process's records): 300 lengths
    lengths = range(600, 600 + 37 * 300, 37)
    assert len({padding.bucket(T) for T in lengths}) <= 18


@pytest.mark.parametrize("nu", [1, 16])
def test_padded_criterion_and_gradient_equal(nu):
    T = 600
    y, u = _record(T, nu)
    theta = jnp.asarray(np.r_[0.85, np.full(nu, 0.3)])
    args = (jnp.asarray(y), jnp.asarray(u))
    Tp = padding.bucket(T)
    assert Tp > T
    padded = padding.pad_time(args, T, Tp)
    assert padded[0].shape == (Tp,) and padded[1].shape == (Tp, nu)
    n = jnp.asarray(T)

    def plain(th):
        return jnp.mean(_oe_residual(th, args) ** 2)

    def masked(th):
        return padding.masked_cost(_oe_residual, th, padded, n)

    v0, g0 = jax.value_and_grad(plain)(theta)
    v1, g1 = jax.value_and_grad(masked)(theta)
    np.testing.assert_allclose(v1, v0, rtol=1e-12)
    np.testing.assert_allclose(g1, g0, rtol=1e-12, atol=1e-14)
    # the Jacobian's rows past T are zero, those before T the unpadded ones
    J0 = jax.jacfwd(lambda th: _oe_residual(th, args))(theta)
    J1 = jax.jacfwd(lambda th: padding.masked_residual(_oe_residual, th, padded, n))(theta)
    np.testing.assert_allclose(J1[:T], J0, rtol=1e-12, atol=1e-14)
    assert not np.any(np.asarray(J1[T:]))


def test_masked_rows_ignore_nonfinite_padding():
    T = 100
    y, u = _record(T, 1)
    yp, up = (np.array(x) for x in padding.pad_time((y, u), T, 112))
    yp[T:] = np.nan                                # a tail whose residual is not finite
    theta = jnp.asarray([0.9, 0.3])
    n = jnp.asarray(T)
    v, g = jax.value_and_grad(lambda th: padding.masked_cost(_oe_residual, th, (yp, up), n))(theta)
    ref, gref = jax.value_and_grad(lambda th: jnp.mean(_oe_residual(th, (y, u)) ** 2))(theta)
    np.testing.assert_allclose(v, ref, rtol=1e-12)
    np.testing.assert_allclose(g, gref, rtol=1e-12)


@pytest.mark.parametrize("solver", ["lm", "gn"])
def test_padded_fit_equals_unpadded(solver):
    y, u = _record(637, 2, seed=3)
    args = (jnp.asarray(y), jnp.asarray(u))
    starts = np.array([[0.5, 0.1, 0.1], [0.7, 0.2, 0.1]]) if solver == "lm" else \
        np.array([[0.88, 0.25, 0.35]])               # undamped Gauss-Newton: a close start
    a = pem.minimize(_oe_residual, starts, args, solver=solver)
    b = pem.minimize(_oe_residual, starts, args, solver=solver, pad=False)
    np.testing.assert_allclose(a.theta, b.theta, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(a.cost, b.cost, rtol=1e-10)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-5, atol=1e-14)
    np.testing.assert_allclose(a.theta, [0.9, 0.2, 0.4], atol=0.05)


def test_padded_matrix_free_equals_unpadded():
    y, u = _record(300, 1, seed=4)
    args = (jnp.asarray(y), jnp.asarray(u))
    a = matrix_free.minimize_matrix_free(_oe_residual, np.array([0.5, 0.1]), args)
    b = matrix_free.minimize_matrix_free(_oe_residual, np.array([0.5, 0.1]), args, pad=False)
    np.testing.assert_allclose(a.theta, b.theta, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(a.cost, b.cost, rtol=1e-9)


@pytest.mark.parametrize("ny", [1, 16])
def test_minimize_many_padded_time_axis(ny):
    """`minimize_many` pads axis 1 (axis 0 is the problem): a library residual
    (`statespace.diagonal_residual`), padded against unpadded."""
    T, nu = 200, 2
    rng = np.random.default_rng(5)
    du = rng.uniform(-0.5, 0.5, (ny, T, nu))
    ys = np.empty((ny, T))
    for i in range(ny):
        x = 0.0
        for t in range(T):
            ys[i, t] = x
            x = 0.8 * x + du[i, t] @ np.array([0.3, 0.1 * (i % 3)])
    args = {"y": ys, "du": du, "dw": np.zeros((ny, T, 1))}
    start = np.tile([0.5, 0.1, 0.1, 0.0, 0.0], (ny, 1))
    a = pem.minimize_many(diagonal_residual, start, args, batch="map")
    b = pem.minimize_many(diagonal_residual, start, args, batch="map", pad=False)
    np.testing.assert_allclose(a.theta, b.theta, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(a.cost, b.cost, rtol=1e-9, atol=1e-20)


def test_compiled_programs_do_not_grow_with_record_lengths():
    """Five lengths in one bucket compile one solve; unpadded, one each (the counter sees it)."""
    runtime.count_compiles()
    lengths = [580, 590, 600, 610, 620]               # bucket 640
    assert {padding.bucket(T) for T in lengths} == {640}
    records = [_record(T, 2, seed=T) for T in lengths]
    starts = np.array([[0.5, 0.1, 0.1]])

    def fits(pad):
        counts = []
        for y, u in records:
            c0 = runtime.compiled_programs()
            pem.minimize(_oe_residual, starts, (y, u), pad=pad, max_steps=20)
            counts.append(runtime.compiled_programs() - c0)
        return counts

    padded = fits(True)
    assert sum(padded[1:]) == 0, padded
    unpadded = fits(False)
    assert all(c >= 1 for c in unpadded), unpadded
