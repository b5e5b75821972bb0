import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

from jthermo.errors import ModelError
from jthermo.models.polynomial import (
    ARMAX,
    ARX,
    OE,
    BoxJenkins,
    Polynomial,
    ar_filter,
    fir_monic,
    lagged,
    poly_from_reflection,
    rational_sum,
    reflection_from_poly,
    stabilize,
)
from tests.helpers import central_difference

NY, NU, T = 3, 2, 150


def _stable(rng, n, shape):
    return poly_from_reflection(jnp.asarray(rng.uniform(-0.8, 0.8, shape + (n,))))


def _models():
    rng = np.random.default_rng(0)
    return {
        "arx": ARX(_stable(rng, 2, (NY,)), rng.standard_normal((NY, NU, 2)), nk=1,
                   u0=[0.5, 0.5], y0=[20.0, 21.0, 22.0]),
        "arx_full": ARX(0.1 * rng.standard_normal((NY, NY, 2)), rng.standard_normal((NY, NU, 2)),
                        nk=[[0, 1], [2, 1], [1, 1]]),
        "armax": ARMAX(_stable(rng, 2, (NY,)), rng.standard_normal((NY, NU, 3)),
                       _stable(rng, 1, (NY,)), nk=0),
        "armax_full": Polynomial(a=0.1 * rng.standard_normal((NY, NY, 1)),
                                 b=rng.standard_normal((NY, NU, 1)), c=_stable(rng, 2, (NY,)), nk=2),
        "oe": OE(rng.standard_normal((NY, NU, 2)), _stable(rng, 2, (NY, NU)), nk=1, y0=[1.0, 1.0, 1.0]),
        "bj": BoxJenkins(rng.standard_normal((NY, NU, 2)), _stable(rng, 1, (NY,)),
                         _stable(rng, 2, (NY,)), _stable(rng, 1, (NY, NU)), nk=[[1, 2], [0, 1], [3, 1]]),
    }


@pytest.mark.parametrize("name", list(_models()))
def test_direct_filters_match_statespace(name):
    m = _models()[name]
    rng = np.random.default_rng(1)
    u = jnp.asarray(rng.uniform(0, 1, (T, NU)))
    e = jnp.asarray(rng.standard_normal((T, NY)))
    ss = m.to_statespace()
    np.testing.assert_allclose(m.simulate(u), ss.simulate(u), atol=1e-11)

    def body(x, inp):                       # data from the innovations form with noise e
        uk, ek = inp
        du = uk - ss.u0
        return ss.A @ x + ss.B @ du + ss.K @ ek, ss.y0 + ss.C @ x + ss.D @ du + ek

    _, y = jax.lax.scan(body, jnp.zeros(ss.A.shape[0]), (u, e))
    np.testing.assert_allclose(m.residuals(y, u), e, atol=1e-10)
    np.testing.assert_allclose(ss.residuals(y, u), e, atol=1e-10)
    np.testing.assert_allclose(m.predict(y, u), y - e, atol=1e-10)
    np.testing.assert_allclose(m.impulse_response(5)[0], ss.D, atol=1e-12)


def test_simulate_matches_scipy_lfilter():
    rng = np.random.default_rng(2)
    b = rng.standard_normal((1, 1, 2))
    f = np.array([[[-1.5, 0.7]]])
    m = OE(b, f, nk=2)
    u = rng.standard_normal((T, 1))
    ref = scipy.signal.lfilter(np.r_[0, 0, b[0, 0]], np.r_[1, f[0, 0]], u[:, 0])
    np.testing.assert_allclose(m.simulate(u)[:, 0], ref, atol=1e-12)
    x = jnp.asarray(rng.standard_normal((T, 2)))
    den = jnp.asarray([[0.3, -0.2], [-0.9, 0.1]])
    for j in range(2):
        np.testing.assert_allclose(ar_filter(x, den)[:, j],
                                   scipy.signal.lfilter([1.0], np.r_[1, den[j]], x[:, j]), atol=1e-12)
        np.testing.assert_allclose(fir_monic(x, den)[:, j],
                                   scipy.signal.lfilter(np.r_[1, den[j]], [1.0], x[:, j]), atol=1e-12)


def test_rational_sum_derivative_matches_autodiff_and_differences():
    """The written-out JVP of sum_j B_j/F_j u_j equals differentiating the filter recursion,
    forward and reverse, and central differences (float64)."""
    rng = np.random.default_rng(5)
    ul = lagged(jnp.asarray(rng.standard_normal((60, 3))), 2)         # (60, 3, 3)
    bl = jnp.asarray(rng.standard_normal((3, 3)))
    f = _stable(rng, 2, (3,))

    def plain(ul, bl, f):
        return ar_filter(jnp.einsum("tjl,jl->tj", ul, bl), f).sum(axis=1)

    np.testing.assert_allclose(rational_sum(ul, bl, f), plain(ul, bl, f), atol=1e-12)
    for arg in range(3):
        ref = jax.jacfwd(plain, argnums=arg)(ul, bl, f)
        np.testing.assert_allclose(jax.jacfwd(rational_sum, argnums=arg)(ul, bl, f), ref, atol=1e-10)
        np.testing.assert_allclose(jax.jacrev(rational_sum, argnums=arg)(ul, bl, f), ref, atol=1e-10)
    cost = jax.jit(lambda th: jnp.sum(rational_sum(ul, th[:9].reshape(3, 3), th[9:].reshape(3, 2)) ** 2))
    th = np.concatenate([np.asarray(bl).ravel(), np.asarray(f).ravel()])
    g = np.asarray(jax.grad(cost)(jnp.asarray(th)))
    np.testing.assert_allclose(g, central_difference(cost, th), rtol=1e-6, atol=1e-6 * np.abs(g).max())


def test_reflection_coefficients_give_stable_polynomials():
    rng = np.random.default_rng(3)
    k = rng.uniform(-0.99, 0.99, (20, 4))
    a = np.asarray(poly_from_reflection(jnp.asarray(k)))
    for row in a:
        assert np.max(np.abs(np.roots(np.r_[1.0, row]))) < 1.0
    np.testing.assert_allclose(reflection_from_poly(a), k, atol=1e-9)
    unstable = np.array([-2.5, 1.2])              # roots outside the circle
    assert np.max(np.abs(np.roots(np.r_[1.0, stabilize(unstable)]))) < 1.0
    kap = reflection_from_poly(unstable)
    assert np.all(np.abs(kap) < 1.0)


def test_dcgain_and_orders():
    m = ARX(np.array([[-0.9]]), np.array([[[0.2]]]), nk=1)
    np.testing.assert_allclose(m.dcgain(), [[2.0]], rtol=1e-12)
    assert m.orders == {"na": 1, "nb": 1, "nc": 0, "nd": 0, "nf": 0, "nk": 1}
    assert m.flat_coefficients().shape == (1, 2)


def test_bad_structures():
    with pytest.raises(ModelError, match="nk"):
        ARX(np.zeros((2, 1)), np.zeros((2, 2, 1)), nk=-1)
    with pytest.raises(ModelError, match="shape"):
        ARX(np.zeros((3, 1)), np.zeros((2, 2, 1)))
    with pytest.raises(ModelError, match="full A"):
        Polynomial(a=np.zeros((2, 2, 1)), b=np.zeros((2, 1, 1)), f=np.zeros((2, 1, 1)))
    with pytest.raises(ModelError, match="b"):
        Polynomial(b=np.zeros((2, 1)))
