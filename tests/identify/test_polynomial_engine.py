"""`fit_polynomial(engine="auto")`, the default: the measured rule (`choose_engine`) picks the NumPy
PEM for small problems or one core and the compiled one for large problems on several cores,
runs exactly that engine, and says which (`info["engine"]`, the fit JSON's `engine`)."""

import json

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from jthermo.data import from_arrays  # noqa: E402
from jthermo.errors import ConfigError  # noqa: E402
from jthermo.identify import polynomial as P  # noqa: E402
from jthermo.identify.fit import fit  # noqa: E402
from jthermo.models.polynomial import OE  # noqa: E402


def _data(T=600, seed=3):
    rng = np.random.default_rng(seed)
    true = OE(b=np.array([[[0.2], [0.05]], [[0.04], [0.15]]]), f=np.full((2, 2, 1), -0.9))
    u = np.repeat(rng.uniform(0, 1, (T // 5, 2)), 5, axis=0)
    return from_arrays(u, 25 + np.asarray(true.simulate(u)) + 0.02 * rng.standard_normal((T, 2)))


def test_rule():
    w = P.AUTO_NUMPY_MAX_WORK
    assert P.choose_engine(2, 4, 6000, cores=2) == "numpy"
    assert P.choose_engine(1, 1, w, cores=2) == "numpy"          # the threshold itself: NumPy
    assert P.choose_engine(1, 1, w + 1, cores=2) == "jax"
    assert P.choose_engine(16, 33, 6000, cores=1) == ("numpy")    # one core: nothing to gain
    assert P.choose_engine(16, 33, 6000, cores=16) == ("jax" if 16 * 33 * 6000 > w else "numpy")
    wn = P.AUTO_NUMPY_MAX_WORK_NOISE                               # ARMAX / BJ rows
    assert wn >= w
    assert P.choose_engine(1, 1, wn, noise_model=True, cores=2) == "numpy"
    assert P.choose_engine(1, 1, wn + 1, noise_model=True, cores=2) == "jax"
    for kw in (dict(full_a=True), dict(solver="gn"), dict(batch="vmap")):   # compiled only
        assert P.choose_engine(1, 1, 100, cores=1, **kw) == "jax"


def test_default_is_auto_and_runs_the_chosen_engine():
    assert P.ENGINES[0] == "auto"
    d = _data()
    kw = dict(nb=1, nf=1, nk=1, n_starts=2, offset="rest", ts=d.ts)
    m_auto, i_auto = P.fit_polynomial(d.y, d.u, **kw)
    want = P.choose_engine(2, 4, d.n_samples)
    assert i_auto["engine"] == want
    m_same, i_same = P.fit_polynomial(d.y, d.u, engine=want, **kw)
    # the same engine, starts and steps: the same model to the last bit
    np.testing.assert_array_equal(m_auto.flat_coefficients(), m_same.flat_coefficients())
    assert i_same["engine"] == want


def test_auto_above_the_threshold_compiles(monkeypatch):
    """With the threshold below the problem's work (and two cores), auto runs the compiled PEM
    and reaches the NumPy engine's optimum."""
    d = _data()
    kw = dict(nb=1, nf=1, nk=1, n_starts=2, offset="rest", ts=d.ts)
    monkeypatch.setattr(P, "AUTO_NUMPY_MAX_WORK", 10)
    monkeypatch.setattr(P.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    m_jax, i_jax = P.fit_polynomial(d.y, d.u, **kw)
    m_np, i_np = P.fit_polynomial(d.y, d.u, engine="numpy", **kw)
    assert i_jax["engine"] == "jax" and i_np["engine"] == "numpy"
    np.testing.assert_allclose(i_jax["cost"], i_np["cost"], rtol=1e-7)
    np.testing.assert_allclose(m_jax.flat_coefficients(), m_np.flat_coefficients(), atol=1e-5)


def test_bad_engine_is_one_line():
    d = _data(T=200)
    with pytest.raises(ConfigError, match="engine must be one of auto, jax, numpy"):
        P.fit_polynomial(d.y, d.u, nb=1, nf=1, engine="fast")


def test_fit_result_and_cli_report_the_engine(tmp_path):
    from jthermo import cli
    from jthermo.data import save_csv

    d = _data()
    res = fit(d, "oe", (1, 1, 1), n_starts=2)
    assert res.extra["engine"] == P.choose_engine(2, 4, d.n_samples)
    save_csv(d, tmp_path / "est.csv")
    for engine in ("auto", "numpy"):
        js = tmp_path / f"{engine}.json"
        rc = cli.main(["fit", str(tmp_path / "est.csv"), "--model", "oe", "--orders", "1,1,1",
                       "--engine", engine, "--json", str(js), "--quiet"])
        assert rc == 0
        assert json.loads(js.read_text())["engine"] == res.extra["engine"]
