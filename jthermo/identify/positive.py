"""Simulation-error PEM of the positive (compartmental) state space (`models.positive`).

The parameters are unconstrained reals (logarithms of flows, leaks, heater and sensor gains), so
the Levenberg–Marquardt steps of `pem.minimize` never leave the set of positive, stable models:
the constraint is the parametrisation, not a projection after the fit (jax-sysid enforces
positivity by bounds on the matrices; a bound-free parametrisation keeps the solver unchanged).

Operating point: rest with the heaters off ($u_0 = 0$; `y0` the level at rest, estimated), the
measured signals at their recorded median ($w_0$). The initial state is estimated (`free_x0`)
or zero (the record starts at rest).

Start points: per output a first-order least-squares fit gives a time constant and the gains
(negative gains clipped to a small positive share); with one node per sensor (n = ny) they are
the leaks and heater gains, with a hidden node per sensor (n = 2 ny, the heater's body) the
heaters drive the hidden node, which feeds the sensor node `HIDDEN_SPEEDS` times faster than
the sensor's own leak.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..data import IOData
from ..errors import FitError
from ..models import positive
from .pem import minimize
from .result import FitResult

#: hidden-node feed rates of the start points, in multiples of the sensor's leak
HIDDEN_SPEEDS = (3.0, 10.0, 30.0)
#: time-constant multiples of the start points with one node per sensor
NODE_SCALES = (1.0, 0.4, 2.5)


def positive_residual(theta, args):
    """Simulation error of `models.positive` (theta = [model parameters, x0 (when estimated),
    y0]); `args` holds `y`, `u`, `dw` (deviations of w from w0), `ts` and shape markers."""
    y, u, dw = args["y"], args["u"], args["dw"]
    n, ny, nu, nw = args["nodes"].shape[0], y.shape[1], u.shape[1], dw.shape[1]
    coupled = args["coupled"].shape[0] == 1
    p = positive.n_params(n, ny, nu, nw, coupled)
    Ad, Bd, C, Bwd = positive.discrete(theta[:p], n, ny, nu, nw, args["ts"], coupled)
    free_x0 = theta.shape[0] == p + n + ny
    x0 = theta[p:p + n] if free_x0 else jnp.zeros(n, theta.dtype)
    y0 = theta[theta.shape[0] - ny:]
    drive = u @ Bd.T + dw @ Bwd.T

    def body(x, d):
        return Ad @ x + d, x

    _, xs = jax.lax.scan(body, x0, drive)
    return y - y0 - xs @ C.T


def _first_order(y: np.ndarray, u: np.ndarray, dw: np.ndarray, ts: float):
    """Per output: rate (1/s) and non-negative heater gains (°C per unit) of a first-order
    least-squares fit $y_{k+1} = a y_k + b^\\top u_k + b_w^\\top w_k + c$."""
    X = np.column_stack([y[:-1, 0] * 0, u[:-1], dw[:-1], np.ones(len(u) - 1)])
    rates, gains = [], []
    for i in range(y.shape[1]):
        X[:, 0] = y[:-1, i]
        coef = np.linalg.lstsq(X, y[1:, i], rcond=None)[0]
        a = float(np.clip(coef[0], 0.5, 0.9999))
        g = coef[1:1 + u.shape[1]] / (1.0 - a)
        top = max(float(np.max(np.abs(g))), 1.0)
        rates.append(-np.log(a) / ts)
        gains.append(np.maximum(g, 0.02 * top))
    return np.array(rates), np.stack(gains)


def starts(n: int, ny: int, nu: int, nw: int, rates, gains, coupled: bool) -> list[np.ndarray]:
    """Parameter vectors (`models.positive` layout) of the start points (module docstring)."""
    out = []
    hidden = n >= 2 * ny
    for s in (HIDDEN_SPEEDS if hidden else NODE_SCALES):
        lam = np.full(n, 1e-3 * rates.min())
        flow = np.full((n, n), 1e-3 * rates.min())
        B = np.full((n, nu), 1e-3)
        for i in range(ny):
            if hidden:
                h = ny + i
                lam[i], lam[h] = rates[i], 0.05 * rates[i]
                flow[i, h] = s * rates[i]
                B[h] = gains[i] * rates[i]
                B[i] = 1e-3 * gains[i] * rates[i]
            else:
                lam[i] = rates[i] / s
                B[i] = gains[i] * rates[i] / s
        parts = []
        if coupled and n > 1:
            parts.append(np.log(flow[~np.eye(n, dtype=bool)]))
        parts += [np.log(lam), np.log(np.maximum(B, 1e-12)).ravel(), np.zeros(ny),
                  np.zeros(n * nw)]
        out.append(np.concatenate(parts))
    return out


def fit_positive(data: IOData, n: int, *, free_x0: bool = True, coupled: bool = True,
                 max_steps: int = 100) -> FitResult:
    """Fit the positive state space of `n` nodes (n >= ny) to `data` by simulation-error PEM.

    **Returns:** a `FitResult` whose `model` is the discrete `StateSpace` (u0 = 0, `y0` the
    estimated level at rest, `w0` the signals' medians); `extra["positive"]` holds the
    continuous-time parameter vector, `n`, `coupled`; `cost` the mean squared simulation
    error.
    """
    ny, nu, nw = data.n_outputs, data.n_inputs, data.w.shape[1]
    if n < ny:
        raise FitError(f"positive state space: n = {n} nodes cannot carry {ny} sensors")
    y = np.asarray(data.y, np.float64)
    u = np.asarray(data.u, np.float64)
    w = np.asarray(data.w, np.float64)
    w0 = np.median(w, axis=0) if nw else np.zeros(0)
    dw = w - w0
    level = y.min(axis=0)
    rates, gains = _first_order(y - level, u, dw, data.ts)
    p = positive.n_params(n, ny, nu, nw, coupled)
    tail = []
    if free_x0:
        x0 = np.zeros(n)
        x0[:ny] = y[0] - level
        if n >= 2 * ny:
            x0[ny:2 * ny] = y[0] - level
        tail.append(x0)
    tail.append(level)
    theta0 = np.stack([np.concatenate([s, *tail]) for s in starts(n, ny, nu, nw, rates, gains,
                                                                  coupled)])
    if data.n_samples * ny <= theta0.shape[1]:
        raise FitError(f"positive state space: {data.n_samples} samples are too few for "
                       f"{theta0.shape[1]} parameters")
    args = {"y": jnp.asarray(y), "u": jnp.asarray(u), "dw": jnp.asarray(dw),
            "ts": jnp.asarray(float(data.ts)), "nodes": jnp.zeros(n),
            "coupled": jnp.zeros(1 if coupled else 0)}
    res = minimize(positive_residual, jnp.asarray(theta0), args, max_steps=max_steps,
                   covariance=False, batch="map", screen_steps=10)
    theta = np.asarray(res.theta)
    if not np.all(np.isfinite(theta)):
        raise FitError("positive state space: the estimate is not finite")
    model = positive.statespace(theta[:p], n, ny, nu, nw, data.ts, y0=theta[-ny:], w0=w0,
                                coupled=coupled)
    x0 = theta[p:p + n] if free_x0 else np.zeros(n)
    return FitResult(model=model, family="ss", orders={"n": n}, converged=bool(res.converged),
                     cost=float(res.cost), x0=jnp.asarray(x0),
                     extra={"positive": {"theta": theta[:p].tolist(), "n": n,
                                         "coupled": coupled, "free_x0": free_x0}})


__all__ = ["HIDDEN_SPEEDS", "NODE_SCALES", "fit_positive", "positive_residual", "starts"]
