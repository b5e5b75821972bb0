import numpy as np
import pytest

from jthermo.data import from_arrays
from jthermo.errors import ConfigError, DataError, ModelError
from jthermo.identify.fit import FitResult, fit
from jthermo.identify.orders import estimate_delays, information_criterion, select_orders
from jthermo.models.polynomial import ARX


def _arx_data(T=800, seed=0, noise=0.02):
    rng = np.random.default_rng(seed)
    true = ARX(np.array([[-1.5, 0.7], [-0.9, 0.0]]),
               np.array([[[0.5, 0.2], [0.0, 0.0]], [[0.1, 0.0], [0.4, 0.1]]]),
               nk=[[2, 2], [2, 3]])
    u = np.repeat(rng.standard_normal((T // 3 + 1, 2)), 3, axis=0)[:T]
    ss = true.to_statespace()
    x = np.zeros(ss.A.shape[0])
    y = np.zeros((T, 2))
    e = noise * rng.standard_normal((T, 2))
    A, B, C, K = (np.asarray(m) for m in (ss.A, ss.B, ss.C, ss.K))
    for t in range(T):
        y[t] = C @ x + e[t]
        x = A @ x + B @ u[t] + K @ e[t]
    return true, from_arrays(u, y)


def test_information_criteria():
    rng = np.random.default_rng(0)
    e = rng.standard_normal((1000, 2))
    V = np.linalg.det(e.T @ e / 1000)
    assert information_criterion(e, 10, "aic") == pytest.approx(1000 * np.log(V) + 20)
    assert information_criterion(e, 10, "bic") == pytest.approx(1000 * np.log(V) + 10 * np.log(1000))
    assert information_criterion(e, 10, "fpe") == pytest.approx(V * 1.01 / 0.99)
    with pytest.raises(ConfigError, match="criterion"):
        information_criterion(e, 1, "mdl")


def test_delay_estimate_with_three_sigma_band():
    _, data = _arx_data()
    d = estimate_delays(data, max_lag=6)
    assert d.nk[0, 0] == 2 and d.nk[1, 1] == 3 and d.nk[1, 0] == 2
    assert d.nk[0, 1] == -1                       # no path from u2 to y1
    assert d.common == 2
    # lags before the delay lie inside the band
    assert np.all(np.abs(d.coef[0, 0, :2]) < 3 * d.std[0, 0, :2])


def test_select_orders_arx_by_bic():
    _, data = _arx_data(T=1000, seed=1)
    orders, table = select_orders(data, "arx", criterion="bic", nk=2,
                                  grid={"na": (1, 2, 3), "nb": (1, 2, 3)})
    assert orders["na"] == 2 and orders["nk"] == 2
    assert sum(r["chosen"] for r in table) == 1 and len(table) == 9


def test_fit_arx_auto_orders():
    _, data = _arx_data(T=1000, seed=2)
    res = fit(data, "arx", None, criterion="bic")
    assert isinstance(res, FitResult)
    assert res.orders["nk"] == 2 and res.criterion_table is not None
    assert res.converged and np.isfinite(res.cost)


def test_fit_validates_input():
    _, data = _arx_data(T=200)
    with pytest.raises(ModelError, match="unknown model family"):
        fit(data, "narx", (1, 1, 1))
    with pytest.raises(ModelError, match="takes 3 orders"):
        fit(data, "arx", (1, 1))
    with pytest.raises(ModelError, match="na = nb = 0"):
        fit(data, "arx", (0, 0, 1))
    with pytest.raises(ModelError, match="integer >= 0"):
        fit(data, "oe", (1, 1, -1))
    with pytest.raises(ModelError, match="nb >= 1"):
        fit(data, "bj", (0, 1, 1, 1, 1))
    with pytest.raises(ConfigError, match="criterion"):
        fit(data, "arx", (1, 1, 1), criterion="mdl")
    const = from_arrays(np.ones((200, 2)), data.y)
    with pytest.raises(DataError, match="constant"):
        fit(const, "arx", (1, 1, 1))
    short = from_arrays(data.u[:20], data.y[:20])
    with pytest.raises(DataError, match="too few"):
        fit(short, "arx", (3, 8, 1))
