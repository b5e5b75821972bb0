"""The NumPy PEM engine (`jthermo.identify.pem_numpy`, `fit_polynomial(engine="numpy")`): the
residual equals the compiled `poly_residual`, the written-out Jacobian equals JAX's forward-mode
one and central differences, and a fit reaches the compiled engine's optimum (cost, coefficients,
covariance) while compiling nothing."""

import json

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from tests.helpers import central_difference  # noqa: E402

from jthermo.data import from_arrays  # noqa: E402
from jthermo.errors import ConfigError  # noqa: E402
from jthermo.identify import pem_numpy  # noqa: E402
from jthermo.identify.fit import fit  # noqa: E402
from jthermo.identify.polynomial import PolySpec, fit_polynomial, poly_args, poly_residual  # noqa: E402
from jthermo.models.polynomial import BoxJenkins, poly_from_reflection  # noqa: E402

#: na, nb, nc, nd, nf, common_f, offset: ARMAX, OE (common F), BJ (per-input F), ARARMAX, BJ
STRUCTURES = [(1, 2, 1, 0, 0, False, False), (0, 2, 0, 0, 2, True, True),
              (0, 2, 1, 2, 2, False, True), (2, 1, 2, 1, 0, False, True),
              (0, 1, 1, 1, 1, True, False)]


def _row(rng, na, nb, nc, nd, nf, common_f, offset, T=300, nu=3):
    nk = (1, 2, 0)
    s = PolySpec(m=1, na=na, nb=nb, nc=nc, nd=nd, nf=nf, nu=nu, L=max(nk) + nb - 1,
                 offset=offset, common_f=common_f)
    u, y = rng.standard_normal((T, nu)), rng.standard_normal((T, 1))
    jax_args = tuple(x[0] if hasattr(x, "shape") else x for x in poly_args(y, u, s, (nk,), False))
    return s, y[:, 0], u, np.array(nk), jax_args, 0.3 * rng.standard_normal(s.n_params)


@pytest.mark.parametrize("structure", STRUCTURES)
def test_residual_and_jacobian_match_jax_and_central_differences(structure):
    s, y, u, nk, jax_args, theta = _row(np.random.default_rng(0), *structure)
    eps, J = pem_numpy.row_residual(theta, y, u, nk, s)
    np.testing.assert_allclose(eps, np.asarray(poly_residual(jnp.asarray(theta), jax_args))[:, 0],
                               atol=1e-12)
    J_jax = jax.jacfwd(lambda th: poly_residual(th, jax_args)[:, 0])(jnp.asarray(theta))
    np.testing.assert_allclose(J, np.asarray(J_jax), atol=1e-11 * np.max(np.abs(J)))
    # the gradient of the cost by central differences (independent of both)
    cost = lambda th: np.mean(pem_numpy.row_residual(np.asarray(th), y, u, nk, s, False) ** 2)  # noqa: E731
    np.testing.assert_allclose(2 * J.T @ eps / y.size, central_difference(cost, theta),
                               rtol=1e-6, atol=1e-9)


def test_step_up_and_its_jacobian():
    rho = np.array([0.4, -1.2, 0.7])
    np.testing.assert_allclose(pem_numpy.step_up(np.tanh(rho)),
                               np.asarray(poly_from_reflection(jnp.tanh(jnp.asarray(rho)))),
                               atol=1e-15)
    J = jax.jacfwd(lambda r: poly_from_reflection(jnp.tanh(r)))(jnp.asarray(rho))
    np.testing.assert_allclose(pem_numpy.step_up_jacobian(rho), np.asarray(J), atol=1e-14)


def _bj_data(T, seed):
    rng = np.random.default_rng(seed)
    true = BoxJenkins(np.array([[0.5, 0.2], [0.1, 0.4]]).reshape(2, 2, 1),
                      np.array([[0.4], [0.2]]), np.array([[-0.8], [-0.7]]),
                      np.array([[[-0.9], [-0.9]], [[-0.85], [-0.85]]]), nk=1)
    u = rng.uniform(0, 1, (T, 2))
    e = 0.05 * rng.standard_normal((T, 2))
    y = np.asarray(true.simulate(u)) + np.stack(
        [np.convolve(e[:, i], [1.0, 0.4 - 0.2 * i])[:T] for i in range(2)], 1)
    return from_arrays(u, y)


@pytest.mark.parametrize("family, orders, common_f", [
    ("armax", (1, 1, 1, 1), False), ("oe", (1, 1, 1), True), ("bj", (1, 1, 1, 1, 1), False)])
def test_numpy_engine_reaches_the_compiled_optimum(family, orders, common_f):
    data = _bj_data(1500, 1)
    kw = dict(seed=0, n_starts=2, rest_level=0.0, **({"common_f": True} if common_f else {}))
    ref = fit(data, family, orders, **kw)
    with _no_compiles():
        res = fit(data, family, orders, engine="numpy", **kw)
    assert res.converged
    assert res.cost <= ref.cost * (1 + 1e-7)
    np.testing.assert_allclose(np.asarray(res.model.flat_coefficients()),
                               np.asarray(ref.model.flat_coefficients()), atol=2e-4)
    np.testing.assert_allclose(np.asarray(res.std), np.asarray(ref.std), rtol=2e-2)


class _no_compiles:
    """Fails if JAX compiles a program inside the block (the NumPy engine compiles nothing)."""

    def __enter__(self):
        from jax._src import compiler

        self._mod, self._orig, self.count = compiler, compiler.backend_compile_and_load, 0

        def counted(*a, **k):
            self.count += 1
            return self._orig(*a, **k)

        compiler.backend_compile_and_load = counted
        return self

    def __exit__(self, *exc):
        self._mod.backend_compile_and_load = self._orig
        if exc[0] is None:
            assert self.count == 0, f"{self.count} XLA compiles in the NumPy engine"


def test_engine_errors():
    data = _bj_data(300, 2)
    with pytest.raises(ConfigError, match="engine"):
        fit_polynomial(data.y, data.u, nb=1, nf=1, engine="torch")


def test_cli_engine_option(tmp_path, capsys):
    """`jthermo fit --engine numpy` fits an OE model; on a family without PEM it is refused."""
    from jthermo import cli
    from jthermo.data import save_csv

    data = _bj_data(600, 3)
    save_csv(from_arrays(np.asarray(data.u), 20.0 + np.asarray(data.y)), tmp_path / "est.csv")
    js = tmp_path / "fit.json"
    rc = cli.main(["fit", str(tmp_path / "est.csv"), "--model", "oe", "--orders", "1,1,1",
                   "--engine", "numpy", "--json", str(js), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    assert json.loads(js.read_text())["converged"]
    rc = cli.main(["fit", str(tmp_path / "est.csv"), "--model", "arx", "--engine", "numpy",
                   "--quiet"])
    assert rc == 2 and "--engine" in capsys.readouterr().err


def test_per_output_convergence_is_reported(tmp_path, capsys):
    """The fit JSON lists convergence and the remaining Gauss–Newton gain per output; a step
    cap that stops a row early shows there (and in `converged`)."""
    from jthermo import cli
    from jthermo.data import save_csv

    data = _bj_data(600, 4)
    save_csv(from_arrays(np.asarray(data.u), 20.0 + np.asarray(data.y)), tmp_path / "est.csv")
    reports = []
    for steps in (200, 1):
        res = fit(data, "oe", (1, 1, 1), engine="numpy", max_steps=steps, n_starts=1,
                  extend_rounds=0)
        reports.append((res.converged, res.extra["row_converged"], res.extra["expected_improvement"]))
    (ok, rows, gains), (ok1, rows1, gains1) = reports
    assert ok and all(rows) and max(gains) < 1e-4
    assert not ok1 and not all(rows1) and max(gains1) >= 1e-4
    js = tmp_path / "fit.json"
    assert cli.main(["fit", str(tmp_path / "est.csv"), "--model", "oe", "--orders", "1,1,1",
                     "--json", str(js), "--quiet"]) == 0
    rep = json.loads(js.read_text())
    assert rep["converged_outputs"] == [True, True] and len(rep["expected_improvement"]) == 2


@pytest.mark.parametrize("engine", ["numpy", "jax"])
def test_rows_stopped_while_improving_are_continued(engine):
    """A row stopped at `max_steps` while its Gauss–Newton step would still gain ≥ 0.01 % gets
    further rounds (`extend_rounds`, `pem_numpy.extend_rows`) until it converges: lower cost,
    more steps, `converged` only where the remaining gain is below the tolerance; with
    `extend_rounds=0` the cap is final and the row is reported not converged."""
    data = _bj_data(600, 4)
    kw = dict(nb=1, nf=1, nk=1, n_starts=1, max_steps=1, engine=engine)
    _, cut = fit_polynomial(data.y, data.u, extend_rounds=0, **kw)
    _, cont = fit_polynomial(data.y, data.u, extend_rounds=200, **kw)
    assert not cut["converged"] and np.max(cut["expected_improvement"]) >= 1e-4
    assert cont["converged"] and np.all(cont["row_converged"])
    assert np.max(cont["expected_improvement"]) < 1e-4
    assert np.all(np.asarray(cont["n_steps"]) > 1) and cont["cost"] < cut["cost"]
    # the continued covariance is that of the new point: sigma^2 (J'J)^+ from its Jacobian
    assert np.all(np.isfinite(np.asarray(cont["std"])))
    with pytest.raises(ConfigError, match="extend_rounds"):
        fit_polynomial(data.y, data.u, extend_rounds=-1, **kw)
