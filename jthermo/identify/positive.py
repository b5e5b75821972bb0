"""Simulation-error PEM of the positive (compartmental) state space (`models.positive`).

The parameters are unconstrained reals (logarithms of flows, leaks, heater and sensor gains), so
the Levenberg–Marquardt steps of `pem.minimize` never leave the set of positive, stable models:
the constraint is the parametrisation, not a projection after the fit (jax-sysid enforces
positivity by bounds on the matrices; a bound-free parametrisation keeps the solver unchanged).

Operating point: rest with the heaters off ($u_0 = 0$; `y0` the level at rest, estimated), the
measured signals at their recorded median ($w_0$). The initial state is estimated (`free_x0`)
or zero (the record starts at rest). The level at rest is the surroundings, which no heated
body falls below: $y_{0,i} = \\bar y_i - e^{\\eta_i}$ with the cap $\\bar y_i$ the coldest
reading plus three noise deviations (`level_cap`). Unbounded, a closed-loop record that hovers
at its set point (a printer bed's heat-up and hold) is fitted as a small, fast response around
a level near the set point: a local model whose heater-off steady state is far above the room
(MATLAB's `greyest` bounds a parameter the same way, by its physical range).

Start points: per output a first-order least-squares fit gives a time constant and the gains
(negative gains clipped to a small positive share); with one node per sensor (n = ny) they are
the leaks and heater gains. With a hidden node per sensor (n = 2 ny) the hidden node is either
the heater's body (the heaters drive it, and it feeds the sensor node `HIDDEN_SPEEDS` times
faster than the sensor's own leak) or the sensor's slow surroundings (the heaters drive the
sensor node, which loses heat partly to the room and partly to a body that warms over
`SLOW_SHARES` of the sensor's time constant and gives it back: a printer bed in its frame and
chamber, whose holding power falls for half an hour at a constant temperature).
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
#: slow-surroundings start points: (sensor-node speed, surroundings' speed), in multiples of the
#: first-order fit's rate
SLOW_SHARES = ((1.0, 0.1), (2.0, 0.05), (0.5, 0.02))


def positive_residual(theta, args):
    """Simulation error of `models.positive` (theta = [model parameters, x0 (when estimated),
    eta], the level at rest `y0 = cap - exp(eta)`); `args` holds `y`, `u`, `dw` (deviations of
    w from w0), `ts`, the level's `cap` (`level_cap`) and shape markers."""
    y, u, dw = args["y"], args["u"], args["dw"]
    n, ny, nu, nw = args["nodes"].shape[0], y.shape[1], u.shape[1], dw.shape[1]
    coupled = args["coupled"].shape[0] == 1
    p = positive.n_params(n, ny, nu, nw, coupled)
    Ad, Bd, C, Bwd = positive.discrete(theta[:p], n, ny, nu, nw, args["ts"], coupled)
    free_x0 = theta.shape[0] == p + n + ny
    x0 = theta[p:p + n] if free_x0 else jnp.zeros(n, theta.dtype)
    y0 = args["cap"] - jnp.exp(theta[theta.shape[0] - ny:])
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
        out.append(_pack(flow, lam, B, ny, nw, coupled))
    if hidden and coupled:
        for fast, slow in SLOW_SHARES:
            lam = np.full(n, 1e-3 * rates.min())
            flow = np.full((n, n), 1e-3 * rates.min())
            B = np.full((n, nu), 1e-3)
            for i in range(ny):
                h = ny + i
                lam[i], flow[h, i] = 0.3 * fast * rates[i], 0.7 * fast * rates[i]
                flow[i, h] = lam[h] = slow * rates[i]
                B[i] = gains[i] * rates[i] * fast
                B[h] = 1e-3 * gains[i] * rates[i]
            out.append(_pack(flow, lam, B, ny, nw, coupled))
    return out


def _pack(flow, lam, B, ny: int, nw: int, coupled: bool) -> np.ndarray:
    n = lam.shape[0]
    parts = []
    if coupled and n > 1:
        parts.append(np.log(flow[~np.eye(n, dtype=bool)]))
    parts += [np.log(lam), np.log(np.maximum(B, 1e-12)).ravel(), np.zeros(ny), np.zeros(n * nw)]
    return np.concatenate(parts)


def level_cap(y: np.ndarray) -> np.ndarray:
    """Per output the highest level at rest (the surroundings) a heated body allows: its coldest
    reading plus three noise deviations (the noise from first differences, as `heat.py`)."""
    d = np.diff(y, axis=0)
    sigma = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(2.0)
    return y.min(axis=0) + 3.0 * sigma


def fit_positive(data: IOData, n: int, *, free_x0: bool = True, coupled: bool = True,
                 max_steps: int = 100) -> FitResult:
    """Fit the positive state space of `n` nodes (n >= ny) to `data` by simulation-error PEM.

    **Returns:** a `FitResult` whose `model` is the discrete `StateSpace` (u0 = 0, `y0` the
    estimated level at rest, at most `level_cap`, `w0` the signals' medians);
    `extra["positive"]` holds the
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
    cap = level_cap(y)
    rates, gains = _first_order(y - level, u, dw, data.ts)
    p = positive.n_params(n, ny, nu, nw, coupled)
    tail = []
    if free_x0:
        x0 = np.zeros(n)
        x0[:ny] = y[0] - level
        if n >= 2 * ny:
            x0[ny:2 * ny] = y[0] - level
        tail.append(x0)
    tail.append(np.log(cap - level + 1e-3 * np.maximum(np.ptp(y, axis=0), 1e-3)))
    theta0 = np.stack([np.concatenate([s, *tail]) for s in starts(n, ny, nu, nw, rates, gains,
                                                                  coupled)])
    if data.n_samples * ny <= theta0.shape[1]:
        raise FitError(f"positive state space: {data.n_samples} samples are too few for "
                       f"{theta0.shape[1]} parameters")
    args = {"y": jnp.asarray(y), "u": jnp.asarray(u), "dw": jnp.asarray(dw),
            "ts": jnp.asarray(float(data.ts)), "nodes": jnp.zeros(n), "cap": jnp.asarray(cap),
            "coupled": jnp.zeros(1 if coupled else 0)}
    res = minimize(positive_residual, jnp.asarray(theta0), args, max_steps=max_steps,
                   covariance=False, batch="map", screen_steps=10)
    theta = np.asarray(res.theta)
    if not np.all(np.isfinite(theta)):
        raise FitError("positive state space: the estimate is not finite")
    model = positive.statespace(theta[:p], n, ny, nu, nw, data.ts, y0=cap - np.exp(theta[-ny:]),
                                w0=w0,
                                coupled=coupled)
    x0 = theta[p:p + n] if free_x0 else np.zeros(n)
    return FitResult(model=model, family="ss", orders={"n": n}, converged=bool(res.converged),
                     cost=float(res.cost), x0=jnp.asarray(x0),
                     extra={"positive": {"theta": theta[:p].tolist(), "n": n,
                                         "coupled": coupled, "free_x0": free_x0}})


__all__ = ["HIDDEN_SPEEDS", "NODE_SCALES", "SLOW_SHARES", "fit_positive", "level_cap", "positive_residual", "starts"]
