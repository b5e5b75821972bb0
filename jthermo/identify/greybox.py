"""Grey-box fitting: the physical bed model (`jthermo.models.greybox.BedModel`, thesis eq. 3.5)
fitted by simulation-error PEM.

From temperatures only the ratios $G_i/C_i$ and $n_{ij}/C_i$ are identifiable, so each capacity
is kept at a nominal value (`capacity=`, default `NOMINAL_CAPACITY` = 1000 J/K) and the loss
conductances and heater gains are fitted relative to it, as logarithms (positive by
construction), together with the initial zone temperatures and, when no surroundings
temperature is measured, a constant surroundings temperature.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DataError, FitError
from ..models.greybox import NOMINAL_CAPACITY, BedModel, first_order_start
from .pem import minimize_many
from .result import FitResult, register_fitter


def _zone_sim(theta, args):
    """Simulated temperature (°C) of one zone, `(T, 1)`: theta = [log G_i, log n_i (nu), x0_i, T_s].

    A zone of the bed model is coupled to nothing but the inputs and the surroundings, so each
    zone is its own first-order problem: $a = e^{-G T_s / C}$, the exact zero-order hold."""
    u, w, log_cap, ts = args["u"], args["w"], args["log_cap"], args["ts"]
    nu = u.shape[1]
    rate = jnp.exp(theta[0] - log_cap)
    lam = rate * ts
    one_minus_a = -jnp.expm1(-lam)
    a = 1.0 - one_minus_a
    b = jnp.exp(theta[1:1 + nu] - log_cap) * one_minus_a / rate
    drive = u @ b + one_minus_a * jnp.where(args["measured"], w[:, 0], theta[2 + nu])

    def body(x, d):
        return a * x + d, x

    _, xs = jax.lax.scan(body, theta[1 + nu], drive)
    return xs[:, None]


def _zone_residual(theta, args):
    return args["y"] - _zone_sim(theta, args)


def _zone_residual_fixed(theta, args):
    """As `_zone_residual` with the surroundings fixed at `args["surr"]` (theta without it)."""
    return _zone_residual(jnp.concatenate([theta, args["surr"][None]]), args)


def _per_zone(residual, starts, args, max_steps, screen_steps):
    """All zones' problems `(n, K, p)` solved together (`minimize_many`, vmapped)."""
    return minimize_many(residual, jnp.asarray(starts), args, solver="lm", max_steps=max_steps,
                         throw=False, screen_steps=screen_steps)


def fit_greybox(data, *, seed: int = 0, n_starts: int = 1, capacity: float = NOMINAL_CAPACITY,
                max_steps: int = 100, use_signals: bool | None = None):
    """Fit the bed model (eq. 3.5) to `data` by simulation-error PEM (output-error).

    $\\hat\\theta = \\arg\\min \\sum_t \\|y(t) - \\hat y_{sim}(t, \\theta)\\|^2$ over
    $\\log G_i$, $\\log n_{ij}$, the initial temperatures (and a constant $T_s$ when no
    surroundings are measured), with capacities fixed at `capacity` J/K (only ratios are
    identifiable).

    The zones of the bed model share no state: given the inputs and the surroundings, zone i's
    simulated temperature depends on its own $(G_i, n_{i\\cdot}, T_i(0))$ only, so the criterion
    is a sum of N independent first-order problems with $2 + n_u$ parameters each. They are
    solved together under `vmap` (`jthermo.identify.pem.minimize_many`): the Jacobian is N
    blocks of `(T, 2 + nu)`, never `(T N, N (2 + nu))`, and the bed fits in seconds at N = 19.
    Start values: per-zone first-order ARX least squares, plus `n_starts - 1` random
    perturbations (from `seed`); every start runs 10 steps, the best one to convergence. The
    default is the ARX start alone: on the scale benchmark it gave the best cost in every zone,
    and each further start costs a compilation and a solve.
    Without measured surroundings each zone first fits its own constant $T_s$; the model's
    one $T_s$ is then the median of those, and the zones are refitted with it fixed.

    **Arguments:**
    - `data`: `IOData` with as many outputs (zones) as inputs (heaters) or more; the first
      measured signal `w[:, 0]` is the surroundings temperature (°C) if present and
      `use_signals` is not False; otherwise the surroundings are a constant fitted parameter.
    - The initial state is estimated too, starting from the first measured temperatures
      (`info["x0"]`): a noisy first sample would otherwise bias the fit.

    **Returns:** a `FitResult` whose `model` is the fitted `BedModel`; `covariance` is that of
    `[log G (N), log n (N nu), x0 (N)(, T_s)]`, block diagonal by zone (the $T_s$ variance:
    the spread of the per-zone estimates over N); `converged` holds when every zone converged
    (MATLAB pem's rule: the Gauss–Newton step from the result would lower the zone's cost by less
    than 0.01 %); `extra["zones_not_converged"]` lists the others and
    `extra["expected_improvement"]` gives that relative gain per zone. A heater gain whose
    least-squares value is at or below zero makes its zone creep: its logarithm falls without
    bound at a nearly constant predicted gain (the bound $n_{ij} > 0$ is active), so such a zone
    reports not converged at the step cap although its fit no longer changes.
    Raises `FitError` when a zone's fit is not finite.
    """
    y = np.asarray(data.y, float)
    u = np.asarray(data.u, float)
    n, nu = y.shape[1], u.shape[1]
    if len(y) < 3 * (n + n * nu):
        raise DataError(f"fit_greybox: {len(y)} samples are too few for {n + n * nu} parameters")
    measured = (data.w.shape[1] > 0) if use_signals is None else bool(use_signals)
    if measured and data.w.shape[1] == 0:
        raise DataError("fit_greybox: `use_signals=True` but the data have no measured signal `w`")
    T = len(y)
    w = np.asarray(data.w[:, :1], float) if measured else np.zeros((T, 1))
    t0 = time.perf_counter()
    loss, gain, surr = first_order_start(y, u, w if measured else None, data.ts, capacity)
    pz = 2 + nu
    base = np.column_stack([np.log(loss), np.log(gain), y[0]] + ([] if measured else [np.full(n, surr)]))
    rng = np.random.default_rng(seed)
    starts = [base]
    for _ in range(max(n_starts, 1) - 1):
        pert = base.copy()
        pert[:, :1 + nu] += rng.normal(0.0, 0.3, (n, 1 + nu))
        starts.append(pert)
    starts = np.stack(starts, axis=1)                        # (n, K, p)
    args = {"u": jnp.broadcast_to(jnp.asarray(u), (n, T, nu)),
            "w": jnp.broadcast_to(jnp.asarray(w), (n, T, 1)),
            "y": jnp.asarray(y.T[:, :, None]), "log_cap": jnp.full((n,), np.log(capacity)),
            "surr": jnp.zeros(n), "ts": float(data.ts), "measured": measured}
    screen = 10 if max_steps > 10 else 0
    if measured:
        res = _per_zone(_zone_residual_fixed, starts, args, max_steps, screen)
        theta, s, s_var = res.theta, 0.0, 0.0
    else:
        first = _per_zone(_zone_residual, starts, args, max_steps, screen)
        if not bool(jnp.all(jnp.isfinite(first.cost))):
            raise FitError("fit_greybox: a zone's fit is not finite")
        s_zone = np.asarray(first.theta[:, -1])
        s = float(np.median(s_zone))
        s_var = float(np.var(s_zone) / n)
        args["surr"] = jnp.full((n,), s)
        res = _per_zone(_zone_residual_fixed, first.theta[:, None, :-1], args, max_steps, 0)
        theta = res.theta
    if not (bool(jnp.all(jnp.isfinite(res.cost))) and bool(jnp.all(jnp.isfinite(theta)))):
        raise FitError("fit_greybox: a zone's fit is not finite")
    theta = np.asarray(theta)
    log_loss, log_gain, x0 = theta[:, 0], theta[:, 1:1 + nu], theta[:, 1 + nu]
    model = BedModel(jnp.log(jnp.full((n,), capacity)), jnp.asarray(log_loss),
                     jnp.asarray(log_gain), surroundings=float(np.mean(w)) if measured else s,
                     u_nominal=np.mean(u, axis=0), ts=data.ts, measured_surroundings=measured)
    # block-diagonal covariance in the packing [log G (n), log n (n nu), x0 (n)(, T_s)]
    idx = np.column_stack([np.arange(n), n + nu * np.arange(n)[:, None] + np.arange(nu),
                           n + n * nu + np.arange(n)])
    p_all = n * pz + (0 if measured else 1)
    cov = np.zeros((p_all, p_all))
    zc = np.asarray(res.covariance)
    for i in range(n):
        cov[np.ix_(idx[i], idx[i])] = zc[i]
    if not measured:
        cov[-1, -1] = s_var
    cost = float(jnp.mean(res.cost))
    seconds = time.perf_counter() - t0
    info = {"cost": cost, "zone_costs": np.asarray(res.cost).tolist(),
            "start_costs": np.asarray(res.start_costs).tolist(),
            "n_steps": int(jnp.max(res.n_steps)), "measured_surroundings": measured,
            "zones_not_converged": np.flatnonzero(~np.asarray(res.converged)).tolist(),
            "expected_improvement": np.asarray(res.expected_improvement).tolist(),
            "surroundings": None if measured else s, "x0": x0.tolist()}
    return FitResult(model=model, family="greybox", orders={}, converged=bool(jnp.all(res.converged)),
                     cost=cost, seconds=seconds, covariance=jnp.asarray(cov),
                     std=jnp.sqrt(jnp.clip(jnp.diagonal(jnp.asarray(cov)), 0.0)),
                     extra=info, x0=x0)


@register_fitter(("greybox",), options=fit_greybox)
def fit_greybox_family(data, family: str, orders: dict | None, *, seed: int = 0,
                       n_starts: int = 4, progress=None, **kw) -> FitResult:
    """`fit`'s fitter of the family `greybox` (no orders): `fit_greybox` with options `kw`.

    `fit`'s `n_starts` is not passed on: the grey-box fit keeps its own default (1 start)."""
    del family, orders, n_starts, progress
    return fit_greybox(data, seed=seed, **kw)


__all__ = ["fit_greybox", "fit_greybox_family"]
