"""The ARX screening solves every output and candidate from one QR of the lagged
columns; its criterion equals the one of separate least-squares fits on explicit regressors."""

import numpy as np
import pytest

from jthermo.data import from_arrays
from jthermo.identify.arx import lag_pool, pool_index, pool_lstsq, pool_r
from jthermo.identify.screening import screen_orders


def _explicit_aic(y, u, na, nb, nk):
    """AIC of per-output ARX fits with a constant (diagonal A), regressors built row by row."""
    T, ny = y.shape
    n0 = max(na, nk + nb - 1)
    E = []
    for i in range(ny):
        Phi = np.array([[-y[t - k, i] for k in range(1, na + 1)]
                        + [u[t - nk - k, j] for j in range(u.shape[1]) for k in range(nb)] + [1.0]
                        for t in range(n0, T)])
        theta = np.linalg.lstsq(Phi, y[n0:, i], rcond=None)[0]
        E.append(y[n0:, i] - Phi @ theta)
    E = np.stack(E, axis=1)
    N = E.shape[0]
    p = ny * (na + u.shape[1] * nb + 1)
    return N * np.linalg.slogdet(E.T @ E / N)[1] + 2 * p


def test_screening_criterion_equals_explicit_fits():
    rng = np.random.default_rng(3)
    T, ny = 400, 3
    u = rng.uniform(0, 1, (T, ny))
    y = np.zeros((T, ny))
    for t in range(1, T):
        y[t] = 0.9 * y[t - 1] + u[t - 1] @ np.array([[0.3, 0.1, 0.0], [0.1, 0.3, 0.1], [0.0, 0.1, 0.3]])
    y += 0.05 * rng.standard_normal((T, ny)) + 20.0
    data = from_arrays(u, y)
    _, table = screen_orders(data, "arx", nk=1)
    yd = y - y[:max(1, min(100, T // 100))].mean(axis=0)
    for row in table:
        assert row["aic"] == pytest.approx(_explicit_aic(yd, u, row["na"], row["nb"], 1),
                                           rel=1e-10, abs=1e-6)


def test_pool_lstsq_residual_norm_and_cross_product():
    rng = np.random.default_rng(4)
    y, u = rng.standard_normal((200, 2)), rng.standard_normal((200, 2))
    ix = pool_index(2, 2, 2, 3)
    pool = lag_pool(y, u, 2, 3)
    R = pool_r(pool, 3)
    cols = [np.r_[ix["ylag"][i], ix["ulag"][:, 1:].ravel()] for i in range(2)]
    fits = [pool_lstsq(R, c, ix["y"][i]) for i, c in enumerate(cols)]
    E = np.stack([pool[3:, ix["y"][i]] - pool[3:, c] @ th
                  for i, (c, (th, _)) in enumerate(zip(cols, fits))], axis=1)
    r = np.stack([res for _, res in fits], axis=1)
    np.testing.assert_allclose(r.T @ r, E.T @ E, rtol=1e-10)
