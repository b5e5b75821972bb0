import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.errors import ConfigError, FitError
from jthermo.identify import pem

_TRACES = {"n": 0}


def _linear_residual(theta, args):
    X, y = args
    _TRACES["n"] += 1          # runs only while tracing
    return (y - X @ theta)[:, None]


def _rosen_residual(theta, args):
    # Rosenbrock as least squares: several local behaviours, minimum at (1, 1)
    return jnp.stack([10.0 * (theta[1] - theta[0] ** 2), 1.0 - theta[0]])[None, :]


def _double_well(theta, args):
    # minima at theta = 1.2 (cost 0) and near theta = -1 (cost about 0.125)
    t = theta[0]
    return jnp.stack([(t - 1.2) * (t + 1.0), jnp.where(t < 0, 0.5, 0.0)])[None, :]


@pytest.fixture(scope="module")
def linear_problem():
    rng = np.random.default_rng(0)
    X = rng.standard_normal((400, 3))
    y = X @ np.array([1.0, -2.0, 0.5]) + 0.1 * rng.standard_normal(400)
    return jnp.asarray(X), jnp.asarray(y)


@pytest.mark.parametrize("solver", ["lm", "gn"])
def test_linear_matches_lstsq_and_covariance(linear_problem, solver):
    X, y = linear_problem
    res = pem.minimize(_linear_residual, jnp.zeros(3), (X, y), solver=solver)
    ref, rss, *_ = np.linalg.lstsq(np.asarray(X), np.asarray(y), rcond=None)
    np.testing.assert_allclose(res.theta, ref, atol=1e-9)
    assert bool(res.converged)
    sigma2 = rss[0] / (len(y) - 3)
    cov = sigma2 * np.linalg.inv(np.asarray(X).T @ np.asarray(X))
    np.testing.assert_allclose(res.covariance, cov, rtol=1e-8)
    np.testing.assert_allclose(res.std, np.sqrt(np.diag(cov)), rtol=1e-8)
    np.testing.assert_allclose(res.cost, rss[0] / len(y), rtol=1e-10)


def test_step_cap_counts_as_converged_only_at_the_optimum(linear_problem):
    """MATLAB pem's rule: a solve stopped by `max_steps` is converged when the Gauss–Newton step
    from its point would lower the cost by < 0.01 %; the expected improvement is that step's."""
    X, y = linear_problem
    ref = np.linalg.lstsq(np.asarray(X), np.asarray(y), rcond=None)[0]
    near = pem.minimize(_linear_residual, jnp.asarray(ref) + 1e-5, (X, y), max_steps=1, atol=0.0,
                        rtol=0.0)
    assert bool(near.converged) and float(near.expected_improvement) < 1e-4
    far = pem.minimize(_rosen_residual, jnp.asarray([-1.2, 1.0]), None, max_steps=1)
    assert not bool(far.converged) and float(far.expected_improvement) > 1e-4
    r = np.asarray(_rosen_residual(far.theta, None)).ravel()
    J = np.asarray(jax.jacfwd(lambda th: _rosen_residual(th, None).ravel())(far.theta))
    g = J.T @ r
    np.testing.assert_allclose(far.expected_improvement, g @ np.linalg.pinv(J.T @ J) @ g / (r @ r),
                               rtol=1e-8)


def test_adam(linear_problem):
    X, y = linear_problem
    res = pem.minimize(_linear_residual, jnp.zeros(3), (X, y), solver="adam", max_steps=1500,
                       learning_rate=0.05)
    ref = np.linalg.lstsq(np.asarray(X), np.asarray(y), rcond=None)[0]
    np.testing.assert_allclose(res.theta, ref, atol=1e-4)


def test_no_retrace_same_shapes(linear_problem):
    X, y = linear_problem
    pem.minimize(_linear_residual, jnp.zeros((2, 3)), (X, y))
    n = _TRACES["n"]
    pem.minimize(_linear_residual, jnp.ones((2, 3)), (X, 2.0 * y))
    assert _TRACES["n"] == n


def test_multistart_picks_best():
    starts = jnp.array([[-1.5], [1.5], [-0.8]])
    res = pem.minimize(_double_well, starts, None)
    assert float(res.theta[0]) == pytest.approx(1.2, abs=1e-6)
    assert int(res.best_start) == 1
    assert float(res.cost) == pytest.approx(float(jnp.min(res.start_costs)))
    assert float(jnp.max(res.start_costs)) > float(res.cost) + 0.1


@pytest.mark.parametrize("batch", ["map", "vmap"])
def test_screening_is_short_solves_then_the_best_continued(batch):
    """With `screen_steps`, every start is solved for that many steps and the best one is then
    solved for the rest of `max_steps` from where it stopped: the same as those solves run one
    by one (the mapped variant runs both rounds through one compiled solver)."""
    starts = np.array([[-1.2, 1.0], [2.0, 2.0], [0.0, 0.0], [-0.5, 0.5]])
    S, M = 5, 60
    res = pem.minimize(_rosen_residual, starts, None, max_steps=M, screen_steps=S,
                       covariance=False, batch=batch)
    short = [pem.minimize(_rosen_residual, s, None, max_steps=S, covariance=False) for s in starts]
    lead = int(np.argmin([float(r.cost) for r in short]))
    rest = pem.minimize(_rosen_residual, short[lead].theta, None, max_steps=M - S,
                        covariance=False)
    np.testing.assert_allclose(res.theta, rest.theta, rtol=0, atol=1e-12)
    assert int(res.best_start) == lead
    steps = [int(r.n_steps) for r in short]
    steps[lead] += int(rest.n_steps)
    assert [int(n) for n in res.start_steps] == steps
    assert steps[lead] > S                       # the best start was continued past the screen
    others = [k for k in range(len(starts)) if k != lead]
    np.testing.assert_allclose(np.asarray(res.start_costs)[others],
                               [float(short[k].cost) for k in others], rtol=1e-12, atol=0)


def test_rosenbrock_lm():
    res = pem.minimize(_rosen_residual, jnp.array([-1.2, 1.0]), None, max_steps=500)
    np.testing.assert_allclose(res.theta, [1.0, 1.0], atol=1e-6)


def test_minimize_many(linear_problem):
    X, y = linear_problem
    res = pem.minimize_many(_linear_residual, jnp.zeros((2, 3, 3)), (jnp.stack([X, X]),
                                                                       jnp.stack([y, -y])))
    np.testing.assert_allclose(res.theta[0], -res.theta[1], atol=1e-9)
    assert res.covariance.shape == (2, 3, 3)


def _nan_residual(theta, args):
    return (theta * jnp.nan)[None, :]


def test_errors(linear_problem):
    with pytest.raises(FitError, match="finite"):
        pem.minimize(_nan_residual, jnp.zeros(2), None)
    with pytest.raises(ConfigError, match="solver"):
        pem.minimize(_linear_residual, jnp.zeros(3), linear_problem, solver="bfgs")
    with pytest.raises(ConfigError, match="shape"):
        pem.minimize(_linear_residual, jnp.zeros((1, 1, 3)), linear_problem)


# ------------------------------------------------------------ polynomial PEM costs

from tests.helpers import central_difference  # noqa: E402

from jthermo.data import from_arrays  # noqa: E402
from jthermo.identify.fit import fit  # noqa: E402
from jthermo.identify.polynomial import PolySpec, poly_args, poly_cost  # noqa: E402
from jthermo.models.polynomial import ARMAX, OE, BoxJenkins, poly_from_reflection  # noqa: E402

SPECS = {   # m, na, nb, nc, nd, nf, nu, L, offset, common_f
    "armax": PolySpec(1, 2, 2, 1, 0, 0, 2, 2, True),
    "armax_full": PolySpec(2, 1, 1, 1, 0, 0, 2, 1, False),
    "oe": PolySpec(1, 0, 2, 0, 0, 2, 2, 2, True),
    "bj": PolySpec(1, 0, 1, 2, 1, 1, 2, 1, False),
    "oe_common_f": PolySpec(1, 0, 2, 0, 0, 2, 3, 2, True, True),
    "bj_common_f": PolySpec(1, 0, 1, 2, 1, 1, 3, 1, False, True),
}


@pytest.mark.parametrize("name", list(SPECS))
def test_grad_of_pem_cost_matches_central_differences(name):
    spec = SPECS[name]
    rng = np.random.default_rng(5)
    y = jnp.asarray(np.cumsum(rng.standard_normal((120, 2)), axis=0) * 0.1)
    u = jnp.asarray(rng.uniform(0, 1, (120, spec.nu)))
    args = poly_args(y, u, spec, 1, spec.m > 1)
    one = tuple(a[0] for a in args[:4]) + (spec,)
    theta = jnp.asarray(rng.normal(0, 0.3, spec.n_params))
    g = np.asarray(jax.grad(poly_cost)(theta, one))
    fd = central_difference(lambda th: poly_cost(th, one), np.asarray(theta))
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-9 * np.max(np.abs(fd)))


def _family_data(model, T, seed, noise=0.05):
    """Data from `model` in innovations form: start at rest, u in [0, 1] held 3-12 samples."""
    rng = np.random.default_rng(seed)
    nu = model.n_inputs
    u = np.repeat(rng.uniform(0, 1, (T // 6 + 1, nu)), 6, axis=0)[:T]
    ss = model.to_statespace()
    e = noise * rng.standard_normal((T, model.n_outputs))

    def body(x, inp):
        uk, ek = inp
        du = uk - ss.u0
        return ss.A @ x + ss.B @ du + ss.K @ ek, ss.y0 + ss.C @ x + ss.D @ du + ek

    _, y = jax.lax.scan(body, jnp.zeros(ss.A.shape[0]), (jnp.asarray(u), jnp.asarray(e)))
    return from_arrays(u, np.asarray(y))


def _fit_percent(y, yhat):
    y, yhat = np.asarray(y), np.asarray(yhat)
    return np.mean(100 * (1 - np.linalg.norm(y - yhat, axis=0) / np.linalg.norm(y - y.mean(0), axis=0)))


def _true_models():
    b = np.array([[[0.20, 0.05], [0.04, 0.01]], [[0.03, 0.01], [0.25, 0.06]]])   # (2, 2, 2)
    f = np.array([[[-0.93]], [[-0.95]]])
    return {
        "armax": (ARMAX(np.array([[-0.93], [-0.95]]), b, np.array([[0.5], [0.3]]), nk=1,
                        y0=[20.0, 21.0]), (1, 2, 1, 1)),
        "oe": (OE(b, np.repeat(f, 2, axis=1), nk=1, y0=[20.0, 21.0]), (2, 1, 1)),
        "bj": (BoxJenkins(b, np.array([[0.4], [0.2]]), np.array([[-0.8], [-0.7]]),
                          np.repeat(f, 2, axis=1), nk=1, y0=[20.0, 21.0]), (2, 1, 1, 1, 1)),
    }


@pytest.mark.parametrize("family, common_f", [("armax", False), ("oe", False), ("bj", False),
                                             ("oe", True), ("bj", True)])
def test_fit_recovers_known_model(family, common_f):
    """The true OE/BJ models have one denominator per output, so both F structures hold them."""
    true, orders = _true_models()[family]
    est = _family_data(true, 1200, seed=1)
    val = _family_data(true, 1200, seed=2)
    res = fit(est, family, orders, n_starts=2, seed=0, **({"common_f": True} if common_f else {}))
    assert res.family == family and res.orders["nk"] == 1
    if common_f:   # one F per output, shared by its inputs
        f = np.asarray(res.model.f)
        np.testing.assert_array_equal(f, np.broadcast_to(f[:, :1], f.shape))
    fit_true = _fit_percent(val.y, true.simulate(val.u))
    fit_hat = _fit_percent(val.y, res.model.simulate(val.u))
    assert fit_hat > fit_true - 1.5
    # most true coefficients inside the reported 3-sigma intervals
    err = np.abs(np.asarray(res.model.flat_coefficients() - true.flat_coefficients()))
    assert np.mean(err < 3 * np.asarray(res.std)) >= 0.8
    for poly in ("c", "d", "f"):
        n = getattr(res.model, "n" + poly)
        for row in np.asarray(getattr(res.model, poly)).reshape(-1, max(n, 1)) if n else []:
            assert np.max(np.abs(np.roots(np.r_[1.0, row]))) < 1.0


def test_stable_parametrisation_is_stable():
    k = jnp.tanh(jnp.asarray([5.0, -7.0, 3.0]))
    assert np.max(np.abs(np.roots(np.r_[1.0, np.asarray(poly_from_reflection(k))]))) < 1.0


@pytest.mark.slow
def test_workload_oe_bj_close_to_armax():
    """Printer-like reference workload (N = 4, T = 2000): OE and BJ within 3 points of ARMAX."""
    import sys
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2].parent / "shared" / "bench"))
    workloads = pytest.importorskip("workloads")
    est, val = workloads.estimation_validation(4, 2000, 0)
    data = from_arrays(est["u"], est["y"])
    fits = {}
    for family, orders in [("arx", (2, 2, 1)), ("armax", (2, 2, 2, 1)), ("oe", (1, 1, 1)),
                           ("bj", (1, 1, 1, 1, 1))]:
        res = fit(data, family, orders, n_starts=4)
        fits[family] = workloads.fit_percent(val["y"], np.asarray(res.model.simulate(val["u"])))
    assert fits["oe"] > fits["armax"] - 3
    assert fits["bj"] > fits["armax"] - 3


def test_known_rest_level_is_used_and_checked():
    """`rest_level`: the operating point is rest at the given level (one number or per output),
    in the polynomial families and in N4SID; malformed levels and unknown options are one-line
    `ConfigError`s."""
    from jthermo.errors import ConfigError
    from jthermo.identify.subspace import n4sid

    true, orders = _true_models()["oe"]
    est = _family_data(true, 600, seed=3)
    for level in (20.5, [20.5, 21.5]):
        res = fit(est, "arx", (1, 1, 1), rest_level=level)
        np.testing.assert_array_equal(np.asarray(res.model.y0), np.broadcast_to(level, (2,)))
        np.testing.assert_array_equal(np.asarray(res.model.u0), 0.0)
        assert res.extra["offset"] == "rest"
    ss, _ = n4sid(est, 2, rest_level=[20.0, 21.0])
    np.testing.assert_array_equal(np.asarray(ss.y0), [20.0, 21.0])
    np.testing.assert_array_equal(np.asarray(ss.u0), 0.0)
    for bad, msg in [([1.0, 2.0, 3.0], "one per output"), (float("nan"), "finite"), ("x", "number")]:
        with pytest.raises(ConfigError, match=msg):
            fit(est, "arx", (1, 1, 1), rest_level=bad)
    with pytest.raises(ConfigError, match="offset 'rest'"):
        fit(est, "oe", orders, rest_level=20.0, offset="mean")
    with pytest.raises(ConfigError, match="unknown option `bogus` for family ss"):
        fit(est, "ss", (2,), bogus=1)
