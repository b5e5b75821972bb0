"""Grey-box fitting: the physical bed model (`jthermo.models.greybox.BedModel`, thesis eq. 3.5)
fitted by simulation-error PEM.

From temperatures only the ratios $G_i/C_i$ and $n_{ij}/C_i$ are identifiable, so each capacity
is kept at a nominal value (`capacity=`, default `NOMINAL_CAPACITY` = 1000 J/K) and the loss
conductances and heater gains are fitted relative to it, as logarithms (positive by
construction), together with the initial zone temperatures and, when no surroundings
temperature is measured, a constant surroundings temperature.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DataError, FitError
from ..models.greybox import NOMINAL_CAPACITY, BedModel, first_order_start, zoh
from .pem import minimize
from .result import FitResult, register_fitter


def _unpack(theta, n, nu, measured):
    k = 0
    log_loss = theta[k:k + n]; k += n
    log_gain = theta[k:k + n * nu].reshape(n, nu); k += n * nu
    x0 = theta[k:k + n]; k += n
    surr = theta[k] if not measured else jnp.asarray(0.0, theta.dtype)
    return log_loss, log_gain, x0, surr


def _greybox_sim(theta, args):
    """Simulated zone temperatures (°C) of the bed model with parameters `theta`."""
    u, w, log_cap = args["u"], args["w"], args["log_cap"]
    n, nu = log_cap.shape[0], u.shape[1]
    measured = w.shape[1] > 0
    log_loss, log_gain, y0, surr = _unpack(theta, n, nu, measured)
    c = jnp.exp(log_cap)
    rate = jnp.exp(log_loss) / c
    A = -jnp.diag(rate)
    B = jnp.exp(log_gain) / c[:, None]
    Ad, BB = zoh(A, jnp.concatenate([B, rate[:, None]], axis=1), args["ts"])
    Bd, Bwd = BB[:, :nu], BB[:, nu]
    ts_seq = w[:, 0] if measured else jnp.full((u.shape[0],), surr)

    def body(x, inp):
        uk, sk = inp
        return Ad @ x + Bd @ uk + Bwd * sk, x

    _, xs = jax.lax.scan(body, y0, (u, ts_seq))
    return xs


def _greybox_residual(theta, args):
    return args["y"] - _greybox_sim(theta, args)


def fit_greybox(data, *, seed: int = 0, n_starts: int = 4, capacity: float = NOMINAL_CAPACITY,
                max_steps: int = 100, use_signals: bool | None = None):
    """Fit the bed model (eq. 3.5) to `data` by simulation-error PEM (output-error).

    $\\hat\\theta = \\arg\\min \\sum_t \\|y(t) - \\hat y_{sim}(t, \\theta)\\|^2$ over
    $\\log G_i$, $\\log n_{ij}$ (and a constant $T_s$ when no surroundings are measured), with
    capacities fixed at `capacity` J/K (only ratios are identifiable). Start values: per-zone
    first-order ARX least squares, plus `n_starts - 1` random perturbations (from `seed`),
    solved together with `vmap` by Levenberg–Marquardt (`jthermo.identify.pem.minimize`).

    **Arguments:**
    - `data`: `IOData` with as many outputs (zones) as inputs (heaters) or more; the first
      measured signal `w[:, 0]` is the surroundings temperature (°C) if present and
      `use_signals` is not False; otherwise the surroundings are a constant fitted parameter.
    - The initial state is estimated too, starting from the first measured temperatures
      (`info["x0"]`): a noisy first sample would otherwise bias the fit.

    **Returns:** a `FitResult` whose `model` is the fitted `BedModel`.
    """
    y = np.asarray(data.y, float)
    u = np.asarray(data.u, float)
    n, nu = y.shape[1], u.shape[1]
    if len(y) < 3 * (n + n * nu):
        raise DataError(f"fit_greybox: {len(y)} samples are too few for {n + n * nu} parameters")
    measured = (data.w.shape[1] > 0) if use_signals is None else bool(use_signals)
    if measured and data.w.shape[1] == 0:
        raise DataError("fit_greybox: `use_signals=True` but the data have no measured signal `w`")
    w = np.asarray(data.w[:, :1], float) if measured else np.zeros((len(y), 0))
    t0 = time.perf_counter()
    loss, gain, surr = first_order_start(y, u, w if measured else None, data.ts, capacity)
    base = np.concatenate([np.log(loss), np.log(gain).ravel(), y[0]] + ([] if measured else [[surr]]))
    rng = np.random.default_rng(seed)
    starts = [base]
    for _ in range(max(n_starts, 1) - 1):
        pert = base.copy()
        pert[:n + n * nu] += rng.normal(0.0, 0.3, n + n * nu)
        starts.append(pert)
    args = {"u": jnp.asarray(u), "w": jnp.asarray(w), "y": jnp.asarray(y),
            "log_cap": jnp.log(jnp.full((n,), capacity)), "ts": float(data.ts)}
    res = minimize(_greybox_residual, jnp.asarray(np.stack(starts)), args, solver="lm",
                   max_steps=max_steps, throw=False)
    if not bool(jnp.isfinite(res.cost)):
        raise FitError("fit_greybox: no start point gave a finite cost")
    log_loss, log_gain, x0, s = _unpack(res.theta, n, nu, measured)
    model = BedModel(jnp.log(jnp.full((n,), capacity)), log_loss, log_gain,
                     surroundings=float(np.mean(w)) if measured else s,
                     u_nominal=np.mean(u, axis=0), ts=data.ts, measured_surroundings=measured)
    seconds = time.perf_counter() - t0
    info = {"cost": float(res.cost), "start_costs": np.asarray(res.start_costs).tolist(),
            "n_steps": int(res.n_steps), "measured_surroundings": measured,
            "surroundings": None if measured else float(s), "x0": np.asarray(x0).tolist()}
    fr = FitResult.from_pem(model, res, seconds=seconds, data=data, info=info, family="greybox")
    return dataclasses.replace(fr, x0=np.asarray(info["x0"]))


@register_fitter(("greybox",), options=fit_greybox)
def fit_greybox_family(data, family: str, orders: dict | None, *, seed: int = 0,
                       n_starts: int = 4, progress=None, **kw) -> FitResult:
    """`fit`'s fitter of the family `greybox` (no orders): `fit_greybox` with options `kw`.

    `fit`'s `n_starts` is not passed on: the grey-box fit keeps its own default (4 starts)."""
    del family, orders, n_starts, progress
    return fit_greybox(data, seed=seed, **kw)


__all__ = ["fit_greybox", "fit_greybox_family"]
