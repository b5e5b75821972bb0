"""Prediction-error minimisation of polynomial output rows in NumPy (diagonal A): nothing compiles.

`fit_polynomial(..., engine="numpy")` solves each output row's MISO problem here instead of in
the compiled `pem.minimize_many`: the same residual (`polynomial.poly_residual`, zero initial
conditions), the same parametrisation (C, D, F by reflection coefficients $\\kappa = \\tanh\\rho$),
the same start points and screening, the same covariance and convergence rule, but the Jacobian
is written out as filtered regressors (Ljung 1999, §10.3) and every filter is a
`scipy.signal.lfilter` pass. Per row,

$$\\varepsilon = \\frac{D}{C}\\,v, \\quad v = A y - \\kappa_0 - \\sum_j B_j \\tilde u_j, \\quad
  \\tilde u_j = \\frac{u_j}{F_j}, \\quad z_j = B_j \\tilde u_j,$$

$$\\frac{\\partial\\varepsilon}{\\partial a_k} = \\frac{D}{C} q^{-k} y, \\quad
  \\frac{\\partial\\varepsilon}{\\partial b_{jk}} = -\\frac{D}{C} q^{-n_{k,j}-k}\\tilde u_j, \\quad
  \\frac{\\partial\\varepsilon}{\\partial f_{jk}} = \\frac{D}{C F_j} q^{-k} z_j, \\quad
  \\frac{\\partial\\varepsilon}{\\partial c_k} = -\\frac{1}{C} q^{-k}\\varepsilon, \\quad
  \\frac{\\partial\\varepsilon}{\\partial d_k} = \\frac{1}{C} q^{-k} v,$$

chained through the reflection map by its complex-step Jacobian (exact to rounding). A solve of
a few dozen parameters over a few thousand samples is then milliseconds per step, where the
compiled solve costs seconds of XLA compilation in every fresh process (and about a second of
tracing even with the persistent cache warm; measured by
`python benchmarks/peers_fixed_profile.py`).

The solver is Levenberg–Marquardt with Marquardt's scaling $\\lambda\\,\\mathrm{diag}(J^\\top J)$
(floored at $10^{-4}$ of its largest entry, the 100× range of `pem.minimize`'s Jacobi scaling):
a step that lowers the cost is kept and $\\lambda$ / 3, otherwise $\\lambda$ × 4 (Marquardt's rule,
`marquardt.next_damping`, which the matrix-free solver runs too). It stops when the undamped
Gauss–Newton step would lower the cost by less than `POLISH_TOL` of itself (far below MATLAB
pem's 0.01 %, since steps are cheap), when $\\lambda$ exceeds $10^{10}$, or at `max_steps`;
`converged` is `pem.minimize`'s rule (that improvement < 0.01 %).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from .marquardt import LAMBDA0, next_damping
from .pem import EXPECTED_IMPROVEMENT_TOL, PEMResult

#: the solve continues until the Gauss–Newton step would gain less than this fraction of the cost
POLISH_TOL = 1e-12
#: the least damping of a taken step (`marquardt.next_damping`)
LAMBDA_FLOOR = 1e-12
#: `extend_rows`: further rounds of `max_steps` steps for a row stopped at its step cap while its
#: Gauss–Newton step would still gain at least `EXPECTED_IMPROVEMENT_TOL` (default of `fit_polynomial`)
EXTEND_ROUNDS = 4


def step_up(kappa: np.ndarray) -> np.ndarray:
    """Monic polynomial tails from reflection coefficients (the Levinson step-up recursion,
    `models.polynomial.poly_from_reflection` in NumPy; last axis; complex input allowed)."""
    kappa = np.asarray(kappa)
    a = np.zeros(kappa.shape[:-1] + (0,), kappa.dtype)
    for m in range(kappa.shape[-1]):
        k = kappa[..., m:m + 1]
        a = np.concatenate([a + k * a[..., ::-1], k], axis=-1)
    return a


def step_up_jacobian(rho: np.ndarray) -> np.ndarray:
    """$\\partial\\, \\mathrm{step\\_up}(\\tanh\\rho) / \\partial\\rho$, `(..., n, n)` for `rho (..., n)`
    (leading axes: independent polynomials), by complex steps (no subtraction: exact to rounding)."""
    rho = np.asarray(rho, np.float64)
    n = rho.shape[-1]
    h = 1e-30
    steps = rho[..., None, :] + 1j * h * np.eye(n)                   # (..., n steps, n)
    return np.swapaxes(step_up(np.tanh(steps)).imag / h, -1, -2)


def _delayed(dst: np.ndarray, src: np.ndarray, shifts) -> None:
    """Write the columns of `src (T, n)` delayed by `shifts (n,)` samples (zeros before the
    record) into `dst (T, n)` (a view: the Jacobian's columns), one copy per distinct delay."""
    shifts = np.asarray(shifts, int)
    T = src.shape[0]
    for k in np.unique(shifts):
        cols = np.flatnonzero(shifts == k)
        sel = slice(int(cols[0]), int(cols[-1]) + 1) if cols.size == cols[-1] - cols[0] + 1 else cols
        if isinstance(sel, slice):
            dst[k:, sel] = src[:T - k, sel]
            dst[:k, sel] = 0.0
        else:
            dst[k:, sel] = src[:T - k][:, sel]
            dst[:k, sel] = 0.0


def _shift(x: np.ndarray, k: int) -> np.ndarray:
    """`x` delayed by `k` samples along axis 0, zeros before the record."""
    if k == 0:
        return x
    out = np.zeros_like(x)
    out[k:] = x[:-k]
    return out


def _monic(tail: np.ndarray) -> np.ndarray:
    return np.concatenate([[1.0], tail])


def _filt(b, a, x: np.ndarray) -> np.ndarray:
    """`lfilter(b, a, x)` along axis 0; the identity filter (`b = a = [1]`, e.g. $D/C$ of an
    OE row) returns `x` itself (lfilter would convolve every column separately)."""
    if len(b) == 1 and len(a) == 1 and b[0] == 1.0 and a[0] == 1.0:
        return x
    return lfilter(b, a, x, axis=0)


def _blocks(theta: np.ndarray, s):
    """Split a row's parameter vector (`polynomial.PolySpec` layout): `a (m * na,)`,
    `b (nu, nb)`, `rho_c`, `rho_d`, `rho_f (1 or nu, nf)`, `kappa0` (0 without offset)."""
    k = np.cumsum([0, s.m * s.na, s.nu * s.nb, s.nc, s.nd, s.n_f])
    rho_f = theta[k[4]:k[5]].reshape(1 if s.common_f else s.nu, s.nf)
    kappa0 = theta[s.n_coef] if s.offset else 0.0
    return (theta[:k[1]], theta[k[1]:k[2]].reshape(s.nu, s.nb), theta[k[2]:k[3]],
            theta[k[3]:k[4]], rho_f, kappa0)


def _per_input_filter(x: np.ndarray, f: np.ndarray, common: bool) -> np.ndarray:
    """Column j of `x (T, nu)` filtered by $1/F_j$ (`f (1 or nu, nf)` monic tails; `common`:
    one F for every column)."""
    if common:
        return _filt([1.0], _monic(f[0]), x)
    out = np.empty_like(x)
    for j in range(x.shape[1]):
        out[:, j] = lfilter([1.0], _monic(f[j]), x[:, j])
    return out


def row_residual(theta: np.ndarray, y: np.ndarray, u: np.ndarray, nk, s, jacobian: bool = True):
    """One row's prediction errors `(T,)` (`polynomial.poly_residual` in NumPy) and, with
    `jacobian`, their Jacobian `(T, p)` in the parameters `theta (p,)`.

    `y (T,)` the output, `u (T, nu)` the inputs (deviations), `nk (nu,)` the input delays,
    `s` the row's `PolySpec` (m = 1). The Jacobian is filled column block by column block into
    one preallocated array (`_delayed`: one copy per distinct delay).
    """
    a, b, rc, rd, rf, kappa0 = _blocks(np.asarray(theta, np.float64), s)
    C, D = _monic(step_up(np.tanh(rc))), _monic(step_up(np.tanh(rd)))
    f = step_up(np.tanh(rf))                                         # (1 or nu, nf)
    T, nu = u.shape
    nk = np.asarray(nk, int)
    uf = _per_input_filter(u, f, s.common_f) if s.nf else u
    lag = np.empty((T, nu))
    z = np.zeros((T, nu))
    for k in range(s.nb):                                            # z_j = B_j q^-nk_j uf_j
        _delayed(lag, uf, nk + k)
        z += b[:, k] * lag
    v = y - kappa0 - z.sum(axis=1)
    for k in range(s.na):
        v = v + a[k] * _shift(y, k + 1)
    eps = _filt(D, C, v)
    if not jacobian:
        return eps
    dc = lambda x: _filt(D, C, x)  # noqa: E731
    J = np.empty((T, s.n_params))
    col = 0
    if s.na:
        _delayed(J[:, :s.na], np.repeat(dc(y)[:, None], s.na, axis=1), np.arange(1, s.na + 1))
        col = s.na
    uff = -dc(uf)
    Jb = J[:, col:col + nu * s.nb]
    for k in range(s.nb):                     # column j * nb + k: -D/C uf_j delayed nk_j + k
        _delayed(Jb[:, k::s.nb], uff, nk + k)
    col += nu * s.nb
    for n, rho, x in ((s.nc, rc, lambda: _filt([1.0], C, -eps)), (s.nd, rd, lambda: _filt([1.0], C, v))):
        if n:
            J[:, col:col + n] = _lag_block(x(), n) @ step_up_jacobian(rho)
            col += n
    if s.nf:
        fz = dc(_per_input_filter(z, f, s.common_f))                  # D/(C F_j) z_j
        lags = np.stack([_shift(fz, k + 1) for k in range(s.nf)], axis=2)   # (T, nu, nf)
        Jf = step_up_jacobian(rf)                                   # (1 or nu, nf, nf)
        if s.common_f:
            J[:, col:col + s.nf] = lags.sum(axis=1) @ Jf[0]
        else:
            J[:, col:col + nu * s.nf] = np.einsum("tjk,jkl->tjl", lags, Jf).reshape(T, -1)
        col += s.n_f
    if s.offset:
        J[:, col] = -dc(np.ones_like(y))
    return eps, J


def _lag_block(x: np.ndarray, n: int) -> np.ndarray:
    """`(T, n)`: `x (T,)` delayed by 1 .. n samples."""
    out = np.empty((x.size, n))
    _delayed(out, np.repeat(x[:, None], n, axis=1), np.arange(1, n + 1))
    return out


def _gn_quantities(eps: np.ndarray, J: np.ndarray):
    """$g = J^\\top\\varepsilon$, $H = J^\\top J$, its pseudo-inverse and the relative cost decrease
    of the undamped Gauss–Newton step, $g^\\top H^{+} g / \\|\\varepsilon\\|^2$."""
    g, H = J.T @ eps, J.T @ J
    H_pinv = np.linalg.pinv(H, hermitian=True)
    return g, H, H_pinv, float(g @ H_pinv @ g) / max(float(eps @ eps), np.finfo(float).tiny)


def _covariance(eps: np.ndarray, H_pinv: np.ndarray, p: int) -> np.ndarray:
    """$\\hat\\sigma^2 (J^\\top J)^{+}$, $\\hat\\sigma^2 = \\sum\\varepsilon^2 / (T - p)$ (NaN-free)."""
    cov = float(eps @ eps) / max(eps.size - p, 1) * H_pinv
    return np.where(np.isfinite(cov), cov, np.inf)


def lm_row(theta0: np.ndarray, y, u, nk, s, max_steps: int):
    """Levenberg–Marquardt from `theta0` (module docstring); returns `(theta, cost, steps)`
    with cost the mean squared prediction error (inf when not finite)."""
    th = np.asarray(theta0, np.float64).copy()
    eps, J = row_residual(th, y, u, nk, s)
    cost = float(np.mean(eps ** 2))
    if not np.isfinite(cost):
        return th, np.inf, 0
    lam, steps, fresh = LAMBDA0, 0, True
    while steps < max_steps and lam < 1e10:
        if fresh:
            g, H, _, gain = _gn_quantities(eps, J)
            if gain < POLISH_TOL:
                break
            scale = np.maximum(np.diagonal(H), 1e-4 * np.max(np.diagonal(H)) + 1e-300)
        steps += 1
        try:
            delta = -np.linalg.solve(H + lam * np.diag(scale), g)
        except np.linalg.LinAlgError:
            lam, fresh = float(next_damping(lam, False, LAMBDA_FLOOR)), False
            continue
        new = th + delta
        e_new = row_residual(new, y, u, nk, s, jacobian=False)
        c_new = float(np.mean(e_new ** 2))
        fresh = bool(np.isfinite(c_new) and c_new < cost)
        if fresh:
            th, cost = new, c_new
            eps, J = row_residual(th, y, u, nk, s)
        lam = float(next_damping(lam, fresh, LAMBDA_FLOOR))
    return th, cost, steps


def minimize_rows(starts: np.ndarray, y: np.ndarray, u: np.ndarray, nkt, s, *, max_steps: int,
                  screen_steps: int, covariance: bool) -> PEMResult:
    """`pem.minimize_many(poly_residual, ...)` of every output row in NumPy: `starts (ny, K, p)`,
    `y (T, ny)`, `u (T, nu)` deviations, delays `nkt` (ny rows of nu), `s` the rows' `PolySpec`.

    Each start gets `screen_steps` steps and the best continues to `max_steps` (with K = 1 or
    `screen_steps` 0 or ≥ `max_steps`: every start to `max_steps`); the best finite start is
    kept. Covariance $\\hat\\sigma^2 (J^\\top J)^{+}$, $\\hat\\sigma^2 = \\sum\\varepsilon^2 / (T - p)$.

    **Returns:** a `PEMResult` of NumPy arrays with a leading row axis.
    """
    ny, K, p = starts.shape
    screen = K > 1 and 0 < screen_steps < max_steps
    out = {k: [] for k in ("theta", "cost", "converged", "n_steps", "start_costs", "covariance",
                           "std", "best_start", "start_steps", "expected_improvement")}
    for i in range(ny):
        args = (y[:, i], u, np.asarray(nkt[i]), s)
        runs = [lm_row(th, *args, screen_steps if screen else max_steps) for th in starts[i]]
        costs = np.array([c if np.isfinite(c) and np.all(np.isfinite(th)) else np.inf
                          for th, c, _ in runs])
        steps = np.array([n for _, _, n in runs])
        if screen and np.isfinite(costs.min()):
            lead = int(np.argmin(costs))
            th, c, n = lm_row(runs[lead][0], *args, max_steps - screen_steps)
            runs[lead] = (th, c, n)
            costs[lead] = c if np.isfinite(c) else np.inf
            steps[lead] += n
        best = int(np.argmin(costs))
        theta = runs[best][0]
        cov = np.full((p, p), np.nan)
        gain = np.nan
        if covariance and np.isfinite(costs[best]):
            eps, J = row_residual(theta, *args)
            _, _, H_pinv, gain = _gn_quantities(eps, J)
            cov = _covariance(eps, H_pinv, p)
        out["theta"].append(theta)
        out["cost"].append(costs[best])
        out["converged"].append(bool(np.isfinite(costs[best]) and gain < EXPECTED_IMPROVEMENT_TOL))
        out["n_steps"].append(steps[best])
        out["start_costs"].append(costs)
        out["covariance"].append(cov)
        out["std"].append(np.sqrt(np.clip(np.diagonal(cov), 0.0, None)))
        out["best_start"].append(best)
        out["start_steps"].append(steps)
        out["expected_improvement"].append(gain)
    return PEMResult(**{k: np.asarray(v) for k, v in out.items()})


def extend_rows(res: PEMResult, y: np.ndarray, u: np.ndarray, nkt, s, *, max_steps: int,
                rounds: int = EXTEND_ROUNDS) -> PEMResult:
    """Continue the rows of `res` (either engine's `PEMResult`, with covariance, rows in `s`'s
    own parameters) that stopped at `max_steps` while still improving, i.e. not converged:
    the Gauss–Newton step from their result would lower the cost by
    $g^\\top (J^\\top J)^{+} g / \\|\\varepsilon\\|^2 \\geq$ `EXPECTED_IMPROVEMENT_TOL`. Each gets
    up to `rounds` more runs of `lm_row` (`max_steps` steps each) until that gain falls below
    the tolerance or a run stops on its own; its theta, cost, steps, covariance, expected
    improvement and `converged` are then those of the new point. Rows that converged, or that
    stopped before the cap, are returned as they were. A NumPy `PEMResult`.
    """
    out = {k: np.array(getattr(res, k)) for k in PEMResult.__dataclass_fields__}
    if rounds < 1:
        return PEMResult(**out)
    p = out["theta"].shape[1]
    stalled = ~out["converged"] & (out["n_steps"] >= max_steps) & np.isfinite(out["cost"])
    for i in np.flatnonzero(stalled):
        args = (y[:, i], u, np.asarray(nkt[i]), s)
        th, gain, steps = out["theta"][i], np.inf, 0
        for _ in range(int(rounds)):
            th, cost, n = lm_row(th, *args, max_steps)
            steps += n
            eps, J = row_residual(th, *args)
            _, _, H_pinv, gain = _gn_quantities(eps, J)
            if gain < EXPECTED_IMPROVEMENT_TOL or n < max_steps:
                break
        if not np.isfinite(cost) or cost > out["cost"][i]:
            continue
        b = out["best_start"][i]
        cov = _covariance(eps, H_pinv, p)
        out["theta"][i], out["cost"][i], out["start_costs"][i, b] = th, cost, cost
        out["n_steps"][i] += steps
        out["start_steps"][i, b] += steps
        out["covariance"][i], out["std"][i] = cov, np.sqrt(np.clip(np.diagonal(cov), 0.0, None))
        out["expected_improvement"][i] = gain
        out["converged"][i] = gain < EXPECTED_IMPROVEMENT_TOL
    return PEMResult(**out)


def coefficient_jacobian(theta: np.ndarray, s) -> np.ndarray:
    """Jacobian `(n_coef, p)` of one row's model coefficients `[a, b, c, d, f]` (`f` per input,
    `(nu, nf)` flattened) in its parameters `theta (p,)` (zero columns for the offset)."""
    _, _, rc, rd, rf, _ = _blocks(np.asarray(theta, np.float64), s)
    n_ab = s.m * s.na + s.nu * s.nb
    Jt = np.zeros((n_ab + s.nc + s.nd + s.nu * s.nf, s.n_params))
    Jt[:n_ab, :n_ab] = np.eye(n_ab)
    k = n_ab
    Jt[k:k + s.nc, k:k + s.nc] = step_up_jacobian(rc)
    k += s.nc
    Jt[k:k + s.nd, k:k + s.nd] = step_up_jacobian(rd)
    k += s.nd
    for j in range(s.nu):
        r = 0 if s.common_f else j
        Jt[k + j * s.nf:k + (j + 1) * s.nf, k + r * s.nf:k + (r + 1) * s.nf] = step_up_jacobian(rf[r])
    return Jt


__all__ = ["EXTEND_ROUNDS", "POLISH_TOL", "coefficient_jacobian", "extend_rows", "lm_row",
           "minimize_rows", "row_residual", "step_up", "step_up_jacobian"]
