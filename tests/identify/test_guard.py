"""Never a silent wrong answer: the realisation of many-input OE/BJ models, the checks on a
fitted model (`identify.guard`) and the repair or failure of a polynomial fit."""

import numpy as np
import pytest
from scipy.signal import lfilter

from jthermo.data import from_arrays
from jthermo.errors import FitError
from jthermo.identify.fit import fit
from jthermo.identify.guard import FitCheck, check_model, spectral_radius
from jthermo.identify.polynomial import guard_polynomial
from jthermo.identify.screening import screen_orders
from jthermo.models.polynomial import ARX, OE, BoxJenkins


def _bed_oe(n=16, pole=0.94):
    """What a fit of an n-zone bed gives: every heater of zone i seen through zone i's pole."""
    rng = np.random.default_rng(0)
    b = rng.uniform(0.01, 0.2, (n, n, 1))
    f = np.full((n, n, 1), -pole) + rng.uniform(-1e-3, 1e-3, (n, n, 1))
    return OE(b, f, nk=1, u0=np.full(n, 0.5), y0=np.full(n, 25.0))


def test_sixteen_input_oe_realisation_is_stable_and_exact():
    # the common denominator of 16 equal first-order F's has a 16-fold root: its companion
    # matrix put poles outside the unit circle (the N = 16 CLI fits of -5e143 %)
    model = _bed_oe()
    rho = spectral_radius(model)
    assert rho < 1.0 and rho == pytest.approx(0.941, abs=2e-3)
    u = np.random.default_rng(1).uniform(0.3, 0.7, (400, 16))
    ss = model.to_statespace()
    np.testing.assert_allclose(np.asarray(ss.simulate(u)), np.asarray(model.simulate(u)), atol=1e-9)


def test_box_jenkins_realisation_predicts_like_the_filters():
    rng = np.random.default_rng(2)
    m = BoxJenkins(rng.normal(size=(2, 3, 2)), np.array([[0.5], [-0.2]]), np.array([[-0.7], [0.3]]),
                   -0.9 + 0.05 * rng.uniform(size=(2, 3, 1)), nk=[[1, 2, 1], [0, 1, 3]])
    u, y = rng.normal(size=(300, 3)), rng.normal(size=(300, 2))
    ss = m.to_statespace()
    np.testing.assert_allclose(np.asarray(ss.residuals(y, u)), np.asarray(m.residuals(y, u)), atol=1e-10)


def _first_order_data(T=1500, seed=0, n=2):
    """A W1-like bed: first order per zone, PRBS holds of 3..15 samples, process noise and
    AR(1) sensor noise (std 0.1), absolute °C from ambient 25."""
    rng = np.random.default_rng(seed)
    holds = np.cumsum(rng.integers(3, 16, (T, n)), axis=0)
    u = np.stack([0.3 + 0.4 * (np.searchsorted(holds[:, j], np.arange(T), side="right") % 2)
                  for j in range(n)], axis=1)
    a = np.linspace(0.92, 0.96, n)
    B = 0.2 * (np.eye(n) + 0.3 * (1 - np.eye(n)))
    w = 0.02 * rng.standard_normal((T, n))
    x = np.zeros((T, n))
    for k in range(T - 1):
        x[k + 1] = a * x[k] + B @ u[k] + w[k]
    v = np.stack([lfilter([0.1 * np.sqrt(1 - 0.49)], [1, -0.7], rng.standard_normal(T))
                  for _ in range(n)], axis=1)
    return from_arrays(u, 25.0 + x + v), a, B


def test_check_model_flags_unstable_non_finite_and_far_below_reference():
    data, a, B = _first_order_data()
    good = ARX(-a[:, None], B[:, :, None], nk=1, u0=np.zeros(2), y0=np.full(2, 25.0))
    c = check_model(good, data, reference=good)
    assert c.ok and c.stable and c.finite and c.fit > 50
    unstable = ARX(np.array([[-1.05], [-0.5]]), B[:, :, None], nk=1, y0=np.full(2, 25.0))
    c = check_model(unstable, data)
    assert not c.ok and "unstable" in c.reason()
    poor = ARX(-a[:, None], 0.2 * B[:, :, None], nk=1, y0=np.full(2, 25.0))
    c = check_model(poor, data, reference=good)
    assert c.stable and c.finite and not c.ok and "far below the ARX reference" in c.reason()
    # an unstable reference sets no bar
    assert check_model(poor, data, reference=unstable).ok
    assert not FitCheck(spectral_radius=0.5, fit=float("-inf")).ok


def test_guard_repairs_with_the_start_or_fails_in_one_line():
    data, a, B = _first_order_data()
    ref = ARX(-a[:, None], B[:, :, None], nk=1, y0=np.full(2, 25.0))
    start = OE(B[:, :, None], np.broadcast_to(-a[:, None, None], (2, 2, 1)), nk=1, y0=np.full(2, 25.0))
    wrong = OE(B[:, :, None], np.full((2, 2, 1), 0.9), nk=1, y0=np.full(2, 25.0))
    model, check, repaired = guard_polynomial(start, {"reference": ref, "start_model": wrong},
                                              data, "oe", {"nb": 1, "nf": 1, "nk": 1})
    assert model is start and check.ok and repaired == ""
    model, check, repaired = guard_polynomial(wrong, {"reference": ref, "start_model": start},
                                              data, "oe", {"nb": 1, "nf": 1, "nk": 1})
    assert model is start and check.ok and "rejected" in repaired
    with pytest.raises(FitError, match=r"^fit: oe \[nb 1, nf 1, nk 1\]: .*far below") as exc:
        guard_polynomial(wrong, {"reference": ref, "start_model": wrong}, data, "oe",
                         {"nb": 1, "nf": 1, "nk": 1})
    assert "\n" not in str(exc.value)


def test_fit_reports_its_checks_and_converged_means_passed():
    data, _, _ = _first_order_data()
    res = fit(data, "oe", (1, 1, 1), n_starts=1)
    assert res.extra["check"]["passed"] and res.extra["check"]["stable"]
    assert res.converged == (res.extra["check"]["passed"] and "repaired" not in res.extra)


def test_screening_finds_first_order_bed_orders():
    data, _, _ = _first_order_data(T=3000, seed=3, n=3)
    for family in ("oe", "bj", "armax"):
        cands, table = screen_orders(data, family)
        o = cands[0]
        assert o["nb"] == 1 and o["nk"] == 1, (family, o)
        assert o.get("nf", o.get("na")) == 1, (family, o)
        assert sum(r["chosen"] for r in table if r["stage"] != "deterministic" or family == "oe") == 1
    arx, _ = screen_orders(data, "arx")
    assert arx[0]["nk"] == 1
