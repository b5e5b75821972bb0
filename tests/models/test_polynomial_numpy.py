"""The NumPy twins of the polynomial model's filters (`jthermo.models.polynomial_numpy`, what the
cold `jthermo fit` uses to compile nothing) against the JAX methods, and the shared compiled
PEM shape (`fit_polynomial(shape_orders=...)`): the same fit as the structure's own solve."""

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from tests.helpers import central_difference  # noqa: E402

from jthermo.data import from_arrays  # noqa: E402
from jthermo.identify.polynomial import (  # noqa: E402
    PolySpec, parameter_embedding, padded_spec, fit_polynomial, poly_args, poly_cost,
)
from jthermo.models import polynomial_numpy as pn  # noqa: E402
from jthermo.models.polynomial import OE, Polynomial  # noqa: E402
from jthermo.validate import compare  # noqa: E402
from jthermo.validate.simulation import estimate_initial_state  # noqa: E402

#: na, nb, nc, nd, nf, nk: ARX, ARMAX, OE, BJ, per-pair delays, a long B with nk 0
ORDERS = [(2, 2, 0, 0, 0, 1), (1, 1, 2, 0, 0, 1), (0, 2, 0, 0, 1, 1), (0, 1, 1, 2, 1, 1),
          (1, 3, 1, 1, 2, ((2, 1), (1, 3), (0, 2))), (3, 1, 0, 0, 0, 0)]


def _model(rng, na, nb, nc, nd, nf, nk, ny=3, nu=2):
    r = lambda *s: 0.3 * rng.uniform(-1, 1, s)  # noqa: E731
    return Polynomial(a=r(ny, na), b=r(ny, nu, nb), c=r(ny, nc), d=r(ny, nd), f=r(ny, nu, nf),
                      nk=nk, u0=rng.uniform(0, 1, nu), y0=20 + rng.uniform(0, 1, ny))


@pytest.mark.parametrize("orders", ORDERS)
def test_numpy_filters_match_the_model(orders):
    rng = np.random.default_rng(3)
    m = _model(rng, *orders)
    T = 300
    u = rng.uniform(0, 1, (T, 2))
    y = 20 + 0.1 * np.cumsum(rng.standard_normal((T, 3)), axis=0)
    assert pn.supported(m)
    np.testing.assert_allclose(pn.simulate(m, u), np.asarray(m.simulate(u)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(pn.residuals(m, y, u), np.asarray(m.residuals(y, u)), rtol=0, atol=1e-12)
    A = np.asarray(m.to_statespace().A)
    rho = np.max(np.abs(np.linalg.eigvals(A))) if A.size else 0.0
    assert abs(pn.spectral_radius(m) - rho) < 1e-9
    # the initial state is one of the realisation's: simulating from it gives the returned yhat
    x0, yhat = pn.initial_state(m, y, u)
    np.testing.assert_allclose(np.asarray(m.simulate(u, None, x0)), yhat, rtol=0, atol=1e-9)
    # and it is the least-squares one: no worse than the generic (JAX) estimate
    x_gen = estimate_initial_state(m, from_arrays(u, y))
    e_gen = np.sum((y - np.asarray(m.simulate(u, None, x_gen))) ** 2)
    assert np.sum((y - yhat) ** 2) <= e_gen * (1 + 1e-9)
    c = compare(m, from_arrays(u, y))
    np.testing.assert_allclose(c["yhat"], yhat, rtol=0, atol=1e-12)


def test_full_a_is_not_served_and_unstable_roots_show():
    rng = np.random.default_rng(4)
    full = Polynomial(a=0.1 * rng.standard_normal((2, 2, 1)), b=rng.standard_normal((2, 1, 1)))
    assert not pn.supported(full)
    unstable = OE(b=np.ones((1, 1, 1)), f=np.array([[[-1.2]]]))
    assert pn.spectral_radius(unstable) == pytest.approx(1.2)


@pytest.mark.parametrize("spec, big", [
    (PolySpec(1, 1, 1, 2, 0, 0, 2, 1, True), dict(na=2, nb=2, nc=2)),
    (PolySpec(1, 0, 1, 1, 2, 1, 2, 1, False), dict(nb=2, nc=1, nd=2, nf=2)),
    (PolySpec(1, 0, 2, 0, 0, 1, 3, 2, True, True), dict(nb=2, nf=2)),
])
def test_masked_cost_in_a_larger_shape_equals_the_own_cost_and_its_gradient(spec, big):
    rng = np.random.default_rng(6)
    T = 150
    y = jnp.asarray(np.cumsum(rng.standard_normal((T, 2)), axis=0) * 0.1)
    u = jnp.asarray(rng.uniform(0, 1, (T, spec.nu)))
    padded = padded_spec(spec, big, ((1,) * spec.nu,) * 2)
    idx = parameter_embedding(spec, padded)
    assert padded.n_params > spec.n_params and len(set(idx)) == spec.n_params
    own = tuple(a[0] for a in poly_args(y, u, spec, 1, False)[:4]) + (spec,)
    mask = np.zeros(padded.n_params)
    mask[idx] = 1.0
    shared = tuple(a[0] for a in poly_args(y, u, padded, 1, False)[:4]) + (padded, jnp.asarray(mask))
    theta = rng.normal(0, 0.3, spec.n_params)
    theta_big = rng.normal(0, 0.3, padded.n_params)       # masked entries: any value
    theta_big[idx] = theta
    assert float(poly_cost(jnp.asarray(theta_big), shared)) == pytest.approx(
        float(poly_cost(jnp.asarray(theta), own)), rel=1e-12)
    g = np.asarray(jax.grad(poly_cost)(jnp.asarray(theta_big), shared))
    fd = central_difference(lambda th: poly_cost(th, shared), theta_big)
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-9 * np.max(np.abs(fd)))
    assert np.all(g[mask == 0] == 0.0)


def test_fit_in_a_shared_shape_is_the_own_fit():
    rng = np.random.default_rng(7)
    T, nu = 600, 2
    true = OE(b=np.array([[[0.2, 0.1], [0.05, 0.02]]]), f=np.array([[[-0.9], [-0.8]]]))
    u = np.repeat(rng.uniform(0, 1, (T // 5, nu)), 5, axis=0)
    y = 25 + np.asarray(true.simulate(u)) + 0.02 * rng.standard_normal((T, 1))
    kw = dict(nb=1, nf=1, nk=1, n_starts=2, max_steps=60, offset="rest", engine="jax")
    m1, i1 = fit_polynomial(y, u, **kw)
    m2, i2 = fit_polynomial(y, u, **kw, shape_orders=dict(nb=2, nf=2, nc=1))
    for name in ("b", "f", "y0"):
        np.testing.assert_allclose(np.asarray(getattr(m2, name)), np.asarray(getattr(m1, name)),
                                   rtol=1e-6, atol=1e-8)
    assert m2.nb == 1 and m2.nf == 1 and i2["converged"] == i1["converged"]
    np.testing.assert_allclose(np.asarray(i2["std"]), np.asarray(i1["std"]), rtol=1e-5)


@pytest.mark.parametrize("orders", ORDERS)
def test_numpy_step_responses_match_the_realisation(orders):
    """What the plausibility check uses for polynomial models (nothing to compile): step
    responses, static gains and state dimension of `to_statespace()`."""
    from jthermo.validate.plausibility import plausibility, step_responses, window

    m = _model(np.random.default_rng(4), *orders)
    ss = m.to_statespace()
    A, B, C, D = (np.asarray(x) for x in (ss.A, ss.B, ss.C, ss.D))
    assert pn.n_states(m) == A.shape[0]
    np.testing.assert_allclose(pn.step_responses(m, 80), step_responses(A, B, C, D, 80),
                               rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(pn.dc_gain(m), C @ np.linalg.solve(np.eye(A.shape[0]) - A, B) + D,
                               rtol=1e-10, atol=1e-12)
    # the check itself: same pairs as from the realisation (a StateSpace takes that path)
    fast, ref = plausibility(m, noise_std=0.01), plausibility(ss, noise_std=0.01)
    assert fast["window_s"] == ref["window_s"] == window(A, B.shape[1]) * float(m.ts)
    for p, q in zip(fast["pairs"], ref["pairs"]):
        assert p["inverse_response"] == q["inverse_response"]
        assert p["wrong_way_C"] == pytest.approx(q["wrong_way_C"], rel=1e-8, abs=1e-12)
        assert p["dc_gain"] == pytest.approx(q["dc_gain"], rel=1e-8)
