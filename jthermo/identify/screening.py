"""Automatic polynomial orders from screening that costs about one fit (no PEM per candidate).

All in NumPy (closed-form least squares and `lfilter` simulations: nothing to compile):

1. The delay $n_k$ from an FIR estimate (`orders.estimate_delays`).
2. ARX: each `(na, nb)` candidate by least squares, judged by the criterion of its one-step
   prediction errors (exact: ARX is its own least-squares problem).
3. The deterministic part of ARMAX, OE and BJ (`nb` and the denominator order `nf`, ARMAX's
   `na`): a high-order ARX is consistent under coloured noise (its A absorbs the noise
   model), so its simulation $\\hat y_h = (B_h/A_h)\\,u$ is a nearly noise-free copy of the
   deterministic response. Each `(nf, nb)` candidate is the least-squares ARX fit of
   $\\hat y_h$ (nearly the output-error estimate, because $\\hat y_h$ carries little noise),
   judged by the criterion of its *simulation* errors on the measured $y$ with the family's
   deterministic parameter count.
4. The noise part (BJ's `nc`, `nd`; ARMAX's `nc`): Hannan–Rissanen on the residual of the
   chosen deterministic part (high-order AR for the innovations, then least squares of an
   ARMA(nd, nc) candidate), judged by the criterion with the noise parameter count.

`fit` then runs one PEM at the chosen orders, and a second at the runner-up only when the
screening criteria of the two lie within `close` (a confirmation, decided by the PEM criterion).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.signal import lfilter

from ..data import IOData, require_excitation
from ..errors import ConfigError, FitError, ModelError
from ..families import ORDER_NAMES
from .arx import lag_pool, pool_index, pool_lstsq, pool_r
from .orders import CRITERIA, estimate_delays

#: screening candidates per order name
SCREEN_GRID = {"na": (1, 2, 3), "nb": (1, 2, 3), "nf": (1, 2, 3), "nc": (0, 1, 2), "nd": (1, 2)}
#: high-order ARX orders tried for the noise-free response, highest first
HIGH_ORDERS = (6, 4, 2)
#: Steiglitz–McBride steps per deterministic candidate
SM_STEPS = 4
#: a runner-up within this many criterion units (AIC / BIC) is confirmed by a PEM fit
CLOSE = 4.0


def _criterion(S: np.ndarray, N: int, p: int, criterion: str) -> float:
    """AIC / BIC / FPE (log scale) from the residual cross-product $S = \\sum_t e e^\\top$ over
    N samples."""
    sign, logdet = np.linalg.slogdet(S / N)
    if sign <= 0 or not np.isfinite(logdet) or p >= N:
        return float("inf")
    if criterion == "aic":
        return float(N * logdet + 2 * p)
    if criterion == "bic":
        return float(N * logdet + p * np.log(N))
    # FPE on the log scale, so that `close` compares like with like
    return float(N * (logdet + np.log((1 + p / N) / (1 - p / N))))


def _gram(e: np.ndarray) -> tuple[np.ndarray, int]:
    return e.T @ e, e.shape[0]


def _arx(y: np.ndarray, u: np.ndarray, na: int, nb: int, nk: int, prefilter=None, pools=None):
    """Least-squares ARX with a constant per output (diagonal A): `a (ny, na)`, `bl (ny, nu,
    nk+nb)` lag coefficients, `c (ny,)`, and the one-step residuals' cross-product `(ny, ny)`
    with their number `T - n0`. `prefilter (ny, n)`: each row's data filtered by $1/A_i$ first
    (a Steiglitz–McBride step). Without one, every output and candidate shares one QR of the
    lagged columns (`arx.pool_r`; `pools` caches it across candidates of a grid)."""
    T, ny = y.shape
    nu = u.shape[1]
    L = nk + nb - 1
    n0 = max(na, L)
    if prefilter is None:
        return _arx_pooled(y, u, na, nb, nk, n0, {} if pools is None else pools)
    a = np.zeros((ny, na))
    bl = np.zeros((ny, nu, L + 1))
    c = np.zeros(ny)
    res = np.empty((T - n0, ny))
    for i in range(ny):
        den = np.concatenate([[1.0], prefilter[i]])
        uf = lfilter([1.0], den, u, axis=0)
        yf = lfilter([1.0], den, y[:, i])
        ulag = np.stack([uf[n0 - l:T - l] for l in range(nk, L + 1)], axis=2).reshape(T - n0, nu * nb)
        ylag = np.stack([-yf[n0 - k:T - k] for k in range(1, na + 1)], axis=1) if na else \
            np.zeros((T - n0, 0))
        one = lfilter([1.0], den, np.ones(T))
        Phi = np.concatenate([ylag, ulag, one[n0:, None]], axis=1)
        theta = np.linalg.lstsq(Phi, yf[n0:], rcond=None)[0]
        res[:, i] = yf[n0:] - Phi @ theta
        a[i] = theta[:na]
        bl[i, :, nk:] = theta[na:na + nu * nb].reshape(nu, nb)
        c[i] = theta[-1]
    return (a, bl, c) + _gram(res)


def _arx_pooled(y, u, na, nb, nk, n0, pools):
    """`_arx` without a prefilter from the pooled QR; `pools` holds `(orders, pool)` and one R
    per first row n0. The pool is kept when a later candidate's lags fit in it."""
    T, ny = y.shape
    nu = u.shape[1]
    L = nk + nb - 1
    key = pools.get("orders")
    if key is None or key[0] < na or key[1] < L:
        key = (max(na, SCREEN_GRID["na"][-1]), max(L, nk + SCREEN_GRID["nb"][-1] - 1))
        pools.clear()
        pools.update(orders=key, pool=lag_pool(y, u, *key))
    if n0 not in pools:
        pools[n0] = pool_r(pools["pool"], n0)
    ix = pool_index(ny, nu, *key)
    R = pools[n0]
    a, bl, c = np.zeros((ny, na)), np.zeros((ny, nu, L + 1)), np.zeros(ny)
    r = np.empty((R.shape[0], ny))
    for i in range(ny):
        cols = np.concatenate([ix["ylag"][i, :na], ix["ulag"][:, nk:L + 1].ravel(), [ix["one"]]])
        theta, r[:, i] = pool_lstsq(R, cols, ix["y"][i])
        a[i] = theta[:na]
        bl[i, :, nk:] = theta[na:na + nu * nb].reshape(nu, nb)
        c[i] = theta[-1]
    return a, bl, c, r.T @ r, T - n0


def _simulate(a: np.ndarray, bl: np.ndarray, c: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Zero-state simulation of $A_i y_i = \\sum_j B_{ij} u_j + c_i$ per output."""
    T, ny = u.shape[0], a.shape[0]
    out = np.empty((T, ny))
    for i in range(ny):
        v = sum(lfilter(bl[i, j], [1.0], u[:, j]) for j in range(u.shape[1])) + c[i]
        out[:, i] = lfilter([1.0], np.concatenate([[1.0], a[i]]), v)
    return out


def _stable(a: np.ndarray) -> bool:
    return all(np.all(np.abs(np.roots(np.concatenate([[1.0], r]))) < 1.0) for r in a)


def _noise_free_response(y, u, nk):
    for n in HIGH_ORDERS:
        a, bl, c, _, _ = _arx(y, u, n, n, nk)
        if _stable(a):
            yh = _simulate(a, bl, c, u)
            if np.all(np.isfinite(yh)):
                return yh
    raise FitError("orders: no stable high-order ARX for screening (the data may not come "
                   "from a stable system)")


def _hannan_rissanen(r: np.ndarray, nc: int, nd: int, n_ar: int = 20) -> np.ndarray:
    """Residuals of an ARMA(nd, nc) fit of `r (T, ny)` per output (Hannan–Rissanen)."""
    T, ny = r.shape
    n0 = n_ar + max(nc, nd)
    out = np.empty((T - n0, ny))
    for i in range(ny):
        x = r[:, i]
        X = np.stack([x[n_ar - k:T - k] for k in range(1, n_ar + 1)], axis=1)
        g = np.linalg.lstsq(X, x[n_ar:], rcond=None)[0]
        ehat = np.concatenate([np.zeros(n_ar), x[n_ar:] - X @ g])
        cols = [x[n0 - k:T - k] for k in range(1, nd + 1)] + \
               [ehat[n0 - k:T - k] for k in range(1, nc + 1)]
        if cols:
            P = np.stack(cols, axis=1)
            out[:, i] = x[n0:] - P @ np.linalg.lstsq(P, x[n0:], rcond=None)[0]
        else:
            out[:, i] = x[n0:]
    return out


def _row(orders: dict, family: str, p: int, value: float, criterion: str, stage: str) -> dict:
    return {**{n: orders[n] for n in ORDER_NAMES[family] if n in orders}, "stage": stage,
            "n_params": p, criterion: value, "chosen": False}


def screen_orders(data: IOData, family: str, *, criterion: str = "aic", nk: int | None = None,
                  grid: dict | None = None, close: float = CLOSE):
    """Polynomial orders of `family` (`arx`, `armax`, `oe`, `bj`) by screening (module docstring).

    **Returns:** `(candidates, table)`: `candidates` the chosen orders (MATLAB's naming, with
    `nk`) first and, when its screening criterion lies within `close` of the best, the
    runner-up; `table` one dict per screened candidate (`stage` `deterministic`, `noise` or
    `arx`, its criterion value, `chosen`).
    """
    if family not in ("arx", "armax", "oe", "bj"):
        raise ModelError(f"screen_orders: no order screening for family {family!r}")
    if criterion not in CRITERIA:
        raise ConfigError(f"screen_orders: criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    require_excitation(data)
    g = {**SCREEN_GRID, **(grid or {})}
    if nk is None:
        nk = estimate_delays(data, max_lag=min(10, max(1, data.n_samples // 20))).common
    nk = int(nk)
    y = np.asarray(data.y, np.float64)
    u = np.asarray(data.u, np.float64)
    y = y - y[:max(1, min(100, len(y) // 100))].mean(axis=0)      # deviations from the start
    ny, nu = y.shape[1], u.shape[1]
    table: list[dict] = []
    if family == "arx":
        pools: dict = {}
        for na, nb in itertools.product(g["na"], g["nb"]):
            if na == 0 and nb == 0:
                continue
            *_, S, N = _arx(y, u, na, nb, nk, pools=pools)
            p = ny * (na + nu * nb + 1)
            table.append(_row({"na": na, "nb": nb, "nk": nk}, family, p,
                              _criterion(S, N, p, criterion), criterion, "arx"))
        return _choose(table, family, criterion, close), table
    yh = _noise_free_response(y, u, nk)
    den = "na" if family == "armax" else "nf"
    per_f = 1 if family == "armax" else nu
    best = None
    pools = {}
    for n_den, nb in itertools.product(g[den], g["nb"]):
        if n_den < 1 or nb < 1:
            continue
        a, bl, c, _, _ = _arx(yh, u, n_den, nb, nk, pools=pools)
        for _ in range(SM_STEPS):     # towards the output-error estimate of yh
            if not _stable(a):
                break
            a, bl, c, _, _ = _arx(yh, u, n_den, nb, nk, prefilter=a)
        if not _stable(a):
            continue
        e = y - _simulate(a, bl, c, u)
        p = ny * (per_f * n_den + nu * nb + 1)
        row = _row({den: n_den, "nb": nb, "nk": nk}, family, p, _criterion(*_gram(e), p, criterion),
                   criterion, "deterministic")
        table.append(row)
        if best is None or row[criterion] < best[0][criterion]:
            best = (row, a, bl, c)
    if best is None:
        raise FitError(f"orders: no stable {family} candidate in the screening grid")
    det = [r for r in table if r["stage"] == "deterministic"]
    if family == "oe":
        return _choose(det, family, criterion, close), table
    row, a, bl, c = best
    if family == "armax":       # the equation error A y - B u - c = C e: an MA(nc)
        A_y = y + sum(a[:, k - 1] * np.roll(y, k, axis=0) * (np.arange(len(y)) >= k)[:, None]
                      for k in range(1, a.shape[1] + 1))
        r = A_y - np.stack([sum(lfilter(bl[i, j], [1.0], u[:, j]) for j in range(nu)) + c[i]
                            for i in range(ny)], axis=1)
        noise = [(nc, 0) for nc in g["nc"] if nc >= 1]
    else:                       # BJ: the simulation residual is C/D e
        r = y - _simulate(a, bl, c, u)
        noise = [(nc, nd) for nc, nd in itertools.product(g["nc"], g["nd"]) if nc + nd > 0]
    noise_rows = []
    for nc, nd in noise:
        e = _hannan_rissanen(r, nc, nd)
        p = ny * (nc + nd)
        o = {n: row[n] for n in ORDER_NAMES[family] if n in row}
        o.update(nc=nc, **({"nd": nd} if family == "bj" else {}))
        noise_rows.append(_row(o, family, p, _criterion(*_gram(e), p, criterion), criterion,
                               "noise"))
    table.extend(noise_rows)
    det_close = [r for r in det if r is not row and r[criterion] - row[criterion] < close]
    chosen = _choose(noise_rows, family, criterion, close)
    # a close deterministic runner-up is confirmed with the chosen noise orders
    if det_close and len(chosen) == 1:
        alt = dict(chosen[0])
        alt.update({n: det_close[0][n] for n in (den, "nb")})
        chosen.append(alt)
    return chosen, table


def _choose(rows: list[dict], family: str, criterion: str, close: float) -> list[dict]:
    ok = [r for r in rows if np.isfinite(r[criterion])]
    if not ok:
        raise FitError(f"orders: no {family} candidate could be screened")
    ok.sort(key=lambda r: r[criterion])
    ok[0]["chosen"] = True
    keep = [ok[0]] + ([ok[1]] if len(ok) > 1 and ok[1][criterion] - ok[0][criterion] < close else [])
    return [{n: r[n] for n in ORDER_NAMES[family]} for r in keep]


__all__ = ["CLOSE", "HIGH_ORDERS", "SCREEN_GRID", "screen_orders"]
