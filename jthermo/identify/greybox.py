"""Grey-box fitting: the physical bed model (`jthermo.models.greybox.BedModel`, thesis eq. 3.5)
fitted by simulation-error PEM.

From temperatures only the ratios $G_i/C_i$ and $n_{ij}/C_i$ are identifiable, so each capacity
is kept at a nominal value (`capacity=`, default `NOMINAL_CAPACITY` = 1000 J/K) and the loss
conductances and heater gains are fitted relative to it, together with the initial zone
temperatures and, when no surroundings temperature is measured, a constant surroundings
temperature.

Each zone is a first-order problem that is linear in all its parameters but one: given the
decay $a_i = e^{-G_i T_s / C_i}$, the simulated temperature is a linear combination of
filtered inputs, the initial temperature's free response and the surroundings' response, so
the heater gains ($\\ge 0$), $T_i(0)$ and $T_s$ follow from a non-negative least-squares
problem, and only $\\log(G_i/C_i)$ is searched (variable projection, Golub & Pereyra 1973).
Everything runs in NumPy: nothing to compile.
"""

from __future__ import annotations

import time

import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize_scalar, nnls
from scipy.signal import lfilter

from ..errors import ConfigError, DataError, FitError
from ..models.greybox import NOMINAL_CAPACITY, BedModel
from .pem import EXPECTED_IMPROVEMENT_TOL
from .result import FitResult, register_fitter

#: the search range of the decay per sample, $G_i T_s / C_i$ (time constants 0.2 to 10^5 samples)
RATE_TS_RANGE = (1e-5, 5.0)
#: points of the coarse grid over `log(G_i / C_i)` before the bracketed Brent search
GRID_POINTS = 15
#: Brent's tolerance on $\\log(G_i / C_i)$
LOG_RATE_TOL = 1e-7
#: a heater gain at the bound 0 is stored as this fraction of the zone's largest gain (its
#: logarithm must be finite); the simulated temperatures change by this fraction at most
GAIN_FLOOR = 1e-12


def _filtered(a: float, x: np.ndarray) -> np.ndarray:
    """$z(t) = a z(t-1) + x(t-1)$, $z(0) = 0$: what a unit-gain input feeds the zone state."""
    return lfilter([0.0, 1.0], [1.0, -a], x, axis=0)


def _columns(lam, zone, ts):
    """Decay `a`, the free columns `F (T, nf)` ($T_i(0)$'s free response $a^t$ and, when
    $T_s$ is fitted, $1 - a^t$), the gain columns `Z (T, nu)` and the target: the measured
    temperature less the known surroundings' response."""
    y, u, mode = zone["y"], zone["u"], zone["mode"]
    a = float(np.exp(-np.exp(lam) * ts))
    at = a ** np.arange(y.shape[0])
    free = [at]
    target = y
    if mode == "free":
        free.append(1.0 - at)
    elif mode == "fixed":
        target = y - zone["surr"] * (1.0 - at)
    else:                                        # measured surroundings w
        target = y - (1.0 - a) * _filtered(a, zone["w"])
    return a, np.stack(free, axis=1), _filtered(a, u), target


def _linear_part(F, Z, target):
    """min over free c and gains b >= 0 of $\\|F c + Z b - y\\|^2$: `(c, b, rss)`.

    From the R of `[F, Z, y]` the free part is eliminated exactly ($c = R_{11}^{-1}(r_1 -
    R_{12} b)$) and the gains solve a small NNLS on $(R_{22}, r_2)$."""
    nf, nu = F.shape[1], Z.shape[1]
    R = np.linalg.qr(np.column_stack([F, Z, target]), mode="r")
    b, res = nnls(R[nf:nf + nu, nf:nf + nu], R[nf:nf + nu, -1])
    c = np.linalg.solve(R[:nf, :nf], R[:nf, -1] - R[:nf, nf:nf + nu] @ b)
    tail = R[nf + nu, -1] if R.shape[0] > nf + nu else 0.0
    return c, b, res ** 2 + tail ** 2


def _profile(lam, zone, ts) -> float:
    """Mean squared simulation error of the zone at $\\log(G/C)$ = `lam`, the linear part at its
    optimum (the variable-projection criterion)."""
    _, F, Z, target = _columns(lam, zone, ts)
    return _linear_part(F, Z, target)[2] / target.shape[0]


def _search(zone, ts, max_steps):
    """$\\log(G/C)$ of one zone: the best of a log-spaced grid, then Brent within its
    neighbours. Returns `(lam, cost, start_cost, n_steps, converged, improvement)`;
    `converged` when Brent met `LOG_RATE_TOL` within `max_steps` iterations, away from the
    range's ends, and the Newton step on the profile would lower the cost by less than
    `EXPECTED_IMPROVEMENT_TOL` (the linear part is exact, so a stationary profile is a
    stationary point of the whole problem)."""
    lo, hi = np.log(np.asarray(RATE_TS_RANGE) / ts)
    grid = np.linspace(lo, hi, GRID_POINTS)
    costs = np.array([_profile(g, zone, ts) for g in grid])
    if not np.any(np.isfinite(costs)):
        raise FitError("fit_greybox: a zone's fit is not finite")
    k = int(np.nanargmin(costs))
    bracket = (grid[max(k - 1, 0)], grid[min(k + 1, GRID_POINTS - 1)])
    res = minimize_scalar(_profile, bounds=bracket, args=(zone, ts), method="bounded",
                          options={"xatol": LOG_RATE_TOL, "maxiter": max(int(max_steps), 1)})
    lam, cost = float(res.x), float(res.fun)
    if not cost <= costs[k]:
        lam, cost = float(grid[k]), float(costs[k])
    h = 1e-4
    cm, cp = _profile(lam - h, zone, ts), _profile(lam + h, zone, ts)
    g, H = (cp - cm) / (2 * h), (cp - 2 * cost + cm) / h ** 2
    improvement = g * g / (2 * H) / cost if H > 0 and cost > 0 else (0.0 if g == 0 else np.inf)
    interior = lo + 1e-3 < lam < hi - 1e-3
    converged = bool(res.success and interior and improvement < EXPECTED_IMPROVEMENT_TOL)
    return lam, cost, float(costs[k]), int(res.nit), converged, float(improvement)


def _zone_fit(zone, ts, capacity, max_steps):
    """One zone: the searched $\\log(G/C)$ and the linear part at it, as physical parameters,
    with their Gauss–Newton covariance in the packing `[log G, log n (nu), x0(, T_s)]`."""
    lam, cost, start, steps, converged, improvement = _search(zone, ts, max_steps)
    a, F, Z, target = _columns(lam, zone, ts)
    c, b, rss = _linear_part(F, Z, target)
    T, nu = Z.shape
    rate = float(np.exp(lam))
    scale = capacity * rate / (1.0 - a)          # n_j = b_j C rate / (1 - a)
    gain = b * scale
    at_zero = gain <= 0.0
    top = float(np.max(gain)) if np.any(~at_zero) else 1.0
    log_gain = np.log(np.where(at_zero, GAIN_FLOOR * top, gain))
    # Gauss–Newton covariance over the free parameters (lam, gains off the bound, c)
    h = 1e-6

    def sim(lam_):
        """The zone's simulated temperature at `lam_` with the linear part held fixed."""
        _, F_, Z_, target_ = _columns(lam_, zone, ts)
        return F_ @ c + Z_ @ b + (target - target_)

    d_lam = (sim(lam + h) - sim(lam - h)) / (2 * h)
    free = np.flatnonzero(~at_zero)
    J = np.column_stack([d_lam, Z[:, free], F])
    sigma2 = rss / max(T - J.shape[1], 1)
    cov_free = sigma2 * np.linalg.pinv(J.T @ J)
    # to [log G, log n_free, x0(, T_s)]: d log n_j / d lam = 1 - a rate ts / (1 - a)
    M = np.zeros((J.shape[1], J.shape[1]))
    M[0, 0] = 1.0
    M[1:1 + free.size, 0] = 1.0 - a * rate * ts / (1.0 - a)
    M[1:1 + free.size, 1:1 + free.size] = np.diag(1.0 / b[free])
    M[1 + free.size:, 1 + free.size:] = np.eye(F.shape[1])
    cov_phys = M @ cov_free @ M.T
    pz = 2 + nu + (F.shape[1] - 1)
    pos = np.concatenate([[0], 1 + free, 1 + nu + np.arange(F.shape[1])])
    cov = np.zeros((pz, pz))
    cov[np.ix_(pos, pos)] = cov_phys
    cov[1 + np.flatnonzero(at_zero), 1 + np.flatnonzero(at_zero)] = np.inf
    return {"log_loss": lam + np.log(capacity), "log_gain": log_gain, "c": c, "cost": cost,
            "start_cost": start, "steps": steps, "converged": converged,
            "improvement": improvement, "cov": cov, "at_zero": np.flatnonzero(at_zero).tolist()}


def _fit_zones(y, u, w, mode, ts, capacity, max_steps, surr=0.0):
    """`_zone_fit` of every zone (column of `y`), surroundings handled as `mode` says."""
    zones = [{"y": y[:, i], "u": u, "w": w, "mode": mode, "surr": surr} for i in range(y.shape[1])]
    return [_zone_fit(z, ts, capacity, max_steps) for z in zones]


def fit_first_order_zones(y, u, ts: float, *, surroundings: float | None = None, max_steps: int = 100):
    """Each zone (column of `y (T, n)`) of the first-order model with constant surroundings,
    fitted by the variable projection above at capacity 1 (rates, not conductances): a list of
    dicts with `log_loss` ($\\log a_i$, 1/s), `log_gain` ($\\log b_{ij}$, °C/s per unit input),
    `c` ($T_i(0)$, then $T_s$ when `surroundings` is None: fitted) and `cost`, `converged`.
    `surroundings` (°C): a known constant surroundings temperature."""
    mode = "free" if surroundings is None else "fixed"
    return _fit_zones(np.asarray(y, float), np.asarray(u, float), None, mode, ts, 1.0, max_steps,
                      0.0 if surroundings is None else float(surroundings))


def fit_greybox(data, *, capacity: float = NOMINAL_CAPACITY, max_steps: int = 100,
                use_signals: bool | None = None, surroundings_max: float | None = None):
    """Fit the bed model (eq. 3.5) to `data` by simulation-error PEM (output-error).

    $\\hat\\theta = \\arg\\min \\sum_t \\|y(t) - \\hat y_{sim}(t, \\theta)\\|^2$ over
    $G_i$, $n_{ij} \\ge 0$, the initial temperatures (and a constant $T_s$ when no
    surroundings are measured), with capacities fixed at `capacity` J/K (only ratios are
    identifiable).

    The zones of the bed model share no state: given the inputs and the surroundings, zone i's
    simulated temperature depends on its own $(G_i, n_{i\\cdot}, T_i(0))$ only, so the criterion
    is a sum of N independent first-order problems. Under the exact zero-order hold,
    $a_i = e^{-G_i T_s / C_i}$ and
    $$\\hat T_i(t) = a_i^t\\, T_i(0) + \\sum_j \\beta_{ij} z_{ij}(t) + T_s (1 - a_i^t), \\qquad
      z_{ij}(t) = a_i z_{ij}(t-1) + u_j(t-1),\\quad \\beta_{ij} = \\frac{n_{ij}}{C_i}
      \\frac{1 - a_i}{G_i / C_i},$$
    linear in $\\beta_{ij} \\ge 0$, $T_i(0)$ and $T_s$ (with measured surroundings their response
    $(1 - a_i)\\sum_k a_i^{t-1-k} T_s(k)$ is known). So each zone's criterion is profiled over
    $\\lambda_i = \\log(G_i/C_i)$ alone, the linear part solved exactly by non-negative least
    squares (`_linear_part`), and $\\lambda_i$ found by a log-spaced grid over `RATE_TS_RANGE`
    and Brent's method within the best grid point's neighbours (at most `max_steps` iterations).
    A heater gain whose unconstrained least-squares value is negative lies on its bound 0 —
    a physical gain cannot be negative — where a logarithmic parametrisation would creep
    towards $-\\infty$ without converging; it is stored as `GAIN_FLOOR` times the zone's largest
    gain (the model's gains are logarithms) and listed in `extra["gains_at_zero"]`.
    Without measured surroundings each zone first fits its own constant $T_s$; the model's
    one $T_s$ is then the median of those, and the zones are refitted with it fixed.

    **Arguments:**
    - `data`: `IOData` with as many outputs (zones) as inputs (heaters) or more; the first
      measured signal `w[:, 0]` is the surroundings temperature (°C) if present and
      `use_signals` is not False; otherwise the surroundings are a constant fitted parameter.
    - `max_steps`: Brent iterations per zone.
    - `surroundings_max`: upper bound of the fitted constant surroundings temperature, °C
      (ignored when the surroundings are measured); default none.
    - The initial state is estimated too (`info["x0"]`): a noisy first sample would
      otherwise bias the fit.

    **Returns:** a `FitResult` whose `model` is the fitted `BedModel`; `covariance` is that of
    `[log G (N), log n (N nu), x0 (N)(, T_s)]`, block diagonal by zone (Gauss–Newton at the
    optimum; a gain on its bound has infinite log-variance; the $T_s$ variance: the spread of
    the per-zone estimates over N); `converged` holds when every zone converged (`_search`: the
    Newton step on its profile would lower its cost by less than 0.01 %, MATLAB pem's rule, and
    the optimum lies inside the search range); `extra["zones_not_converged"]` lists the others
    and `extra["expected_improvement"]` gives that relative gain per zone.
    Raises `FitError` when a zone's fit is not finite.
    """
    y = np.asarray(data.y, float)
    u = np.asarray(data.u, float)
    n, nu = y.shape[1], u.shape[1]
    if len(y) < 3 * (n + n * nu):
        raise DataError(f"fit_greybox: {len(y)} samples are too few for {n + n * nu} parameters")
    if surroundings_max is not None and not np.isfinite(surroundings_max):
        raise ConfigError(f"fit_greybox: surroundings_max must be finite, got {surroundings_max!r}")
    measured = (data.w.shape[1] > 0) if use_signals is None else bool(use_signals)
    if measured and data.w.shape[1] == 0:
        raise DataError("fit_greybox: `use_signals=True` but the data have no measured signal `w`")
    T = len(y)
    w = np.asarray(data.w[:, 0], float) if measured else np.zeros(T)
    ts = float(data.ts)
    t0 = time.perf_counter()
    if measured:
        zones, s, s_var = _fit_zones(y, u, w, "measured", ts, capacity, max_steps), 0.0, 0.0
    else:
        first = _fit_zones(y, u, w, "free", ts, capacity, max_steps)
        s_zone = np.array([z["c"][1] for z in first])
        s = float(np.median(s_zone))
        if surroundings_max is not None and s > float(surroundings_max):
            s = float(surroundings_max)
        s_var = float(np.var(s_zone) / n)
        zones = _fit_zones(y, u, w, "fixed", ts, capacity, max_steps, surr=s)
    log_loss = np.array([z["log_loss"] for z in zones])
    log_gain = np.stack([z["log_gain"] for z in zones])
    x0 = np.array([z["c"][0] for z in zones])
    costs = np.array([z["cost"] for z in zones])
    if not (np.all(np.isfinite(costs)) and np.all(np.isfinite(log_loss))
            and np.all(np.isfinite(log_gain)) and np.all(np.isfinite(x0))):
        raise FitError("fit_greybox: a zone's fit is not finite")
    model = BedModel(jnp.log(jnp.full((n,), capacity)), jnp.asarray(log_loss),
                     jnp.asarray(log_gain), surroundings=float(np.mean(w)) if measured else s,
                     u_nominal=np.mean(u, axis=0), ts=ts, measured_surroundings=measured)
    # block-diagonal covariance in the packing [log G (n), log n (n nu), x0 (n)(, T_s)]
    idx = np.column_stack([np.arange(n), n + nu * np.arange(n)[:, None] + np.arange(nu),
                           n + n * nu + np.arange(n)])
    p_all = n * (2 + nu) + (0 if measured else 1)
    cov = np.zeros((p_all, p_all))
    for i, z in enumerate(zones):
        cov[np.ix_(idx[i], idx[i])] = z["cov"][:2 + nu, :2 + nu]
    if not measured:
        cov[-1, -1] = s_var
    converged = np.array([z["converged"] for z in zones])
    cost = float(np.mean(costs))
    info = {"cost": cost, "zone_costs": costs.tolist(),
            "start_costs": [z["start_cost"] for z in zones],
            "n_steps": max(z["steps"] for z in zones), "measured_surroundings": measured,
            "zones_not_converged": np.flatnonzero(~converged).tolist(),
            "expected_improvement": [z["improvement"] for z in zones],
            "gains_at_zero": [[i, j] for i, z in enumerate(zones) for j in z["at_zero"]],
            "surroundings": None if measured else s, "x0": x0.tolist(),
            "surroundings_bounded": bool(not measured and surroundings_max is not None
                                         and s >= float(surroundings_max))}
    return FitResult(model=model, family="greybox", orders={}, converged=bool(np.all(converged)),
                     cost=cost, seconds=time.perf_counter() - t0, covariance=jnp.asarray(cov),
                     std=jnp.sqrt(jnp.clip(jnp.diagonal(jnp.asarray(cov)), 0.0)),
                     extra=info, x0=x0)


@register_fitter(("greybox",), options=fit_greybox)
def fit_greybox_family(data, family: str, orders: dict | None, *, seed: int = 0,
                       n_starts: int = 4, progress=None, **kw) -> FitResult:
    """`fit`'s fitter of the family `greybox` (no orders): `fit_greybox` with options `kw`.

    `fit`'s `seed` and `n_starts` are not passed on: the grey-box search is deterministic
    (a grid, then Brent, per zone)."""
    del family, orders, seed, n_starts, progress
    return fit_greybox(data, **kw)


__all__ = ["GAIN_FLOOR", "GRID_POINTS", "LOG_RATE_TOL", "RATE_TS_RANGE", "fit_first_order_zones",
           "fit_greybox", "fit_greybox_family"]
