"""Closed-form ARX least squares for MIMO data, and ARX-based start points for ARMAX/OE/BJ.

Each output row is a linear regression (Ljung 1999, §7.3, eq. 7.34):

$$y_i(t) = -\\sum_{k=1}^{n_a}\\sum_{l} a_{ilk}\\, y_l(t-k)
          + \\sum_j \\sum_{k=0}^{n_b-1} b_{ijk}\\, u_j(t - n_{k,ij} - k) + e_i(t),$$

with $l$ ranging over all outputs for a full A and over $l = i$ for a diagonal A. Signals are
zero before $t = 0$ in the regressors, and the first $\\max(n_a, \\max n_k + n_b - 1)$ rows, whose
regressors reach before the record, are left out (as MATLAB's `arx` does). With `offset=True` a
constant column estimates the operating point: $A(q)(y - y_0) = B(q) u + e$ gives the constant
$\\kappa = A(1) y_0$.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import DataError, ModelError
from ..models.polynomial import Polynomial, as_nk


class ARXResult(eqx.Module):
    """Least-squares ARX estimate: the model and, per output, the coefficient covariance in the
    layout of `Polynomial.flat_coefficients` (`[a (m·na), b (nu·nb)]`)."""

    model: Polynomial
    covariance: Float[Array, "ny p p"]
    std: Float[Array, "ny p"]
    cost: Float[Array, ""]             # mean squared one-step prediction error


def arx_regressors(y: Float[Array, "T ny"], u: Float[Array, "T nu"], na: int, nb: int,
                   nk=1, *, full_a: bool = False) -> np.ndarray:
    """Regressor matrices $\\Phi_i$ of every output row, `(ny, T, m·na + nu·nb)` (NumPy:
    copies of lagged samples, exact, and nothing to compile once per candidate order)."""
    y = np.asarray(y)
    u = np.asarray(u)
    T, ny = y.shape
    nu = u.shape[1]
    nkt = as_nk(nk, ny, nu)
    L = max(max(r) for r in nkt) + max(nb, 1) - 1
    Yl = -_lagged(y, na)[:, :, 1:]                                       # (T, ny, na)
    Ul = _lagged(u, L)                                                   # (T, nu, L+1)
    Ub = np.empty((ny, T, nu, nb), np.result_type(u, y))
    for i in range(ny):
        for j in range(nu):
            Ub[i, :, j, :] = Ul[:, j, nkt[i][j]:nkt[i][j] + nb]
    if full_a or ny == 1:
        Ya = np.broadcast_to(Yl.reshape(T, ny * na)[None], (ny, T, ny * na))
    else:
        Ya = np.moveaxis(Yl, 1, 0)                                       # (ny, T, na)
    return np.concatenate([Ya, Ub.reshape(ny, T, nu * nb)], axis=2)


def _lagged(x: np.ndarray, L: int) -> np.ndarray:
    """`out[t, j, l] = x[t - l, j]` for `l = 0..L`, zero before `t = 0` (`filters.lagged`)."""
    T = x.shape[0]
    xp = np.concatenate([np.zeros((L,) + x.shape[1:], x.dtype), x], axis=0)
    return np.stack([xp[L - l:L - l + T] for l in range(L + 1)], axis=-1)


def _solve(Phi, Y, n0, offset):
    """Per-output least squares on rows `n0..T-1` (NumPy: a closed-form problem, solved in
    milliseconds, that would otherwise compile once per candidate order)."""
    Phi = np.asarray(Phi, np.float64)
    Y = np.asarray(Y, np.float64)
    if offset:
        Phi = np.concatenate([Phi, np.ones(Phi.shape[:2] + (1,))], axis=2)
    thetas, covs, rsss = [], [], []
    for P, yi in zip(Phi, Y.T):
        P, yi = P[n0:], yi[n0:]
        theta = np.linalg.lstsq(P, yi, rcond=None)[0]
        r = yi - P @ theta
        T, p = P.shape
        sigma2 = np.sum(r**2) / max(T - p, 1)
        thetas.append(theta)
        covs.append(sigma2 * np.linalg.pinv(P.T @ P, hermitian=True))
        rsss.append(np.sum(r**2))
    return np.stack(thetas), np.stack(covs), np.asarray(rsss)


def first_row(na: int, nb: int, nk) -> int:
    """First sample whose ARX regressors all lie inside the record."""
    L = int(np.max(np.asarray(nk))) + max(nb, 1) - 1
    return max(na, L)


def arx_ls(y: Float[Array, "T ny"], u: Float[Array, "T nu"], na: int, nb: int, nk=1, *,
           full_a: bool = False, offset: bool = False, ts: float = 1.0, u0=None,
           y0=None) -> ARXResult:
    """Least-squares ARX fit of deviation data `y`, `u` (subtract the operating point first).

    **Arguments:**
    - `na`, `nb`, `nk`: orders in MATLAB's meaning (`nk` an int or a `(ny, nu)` array).
    - `full_a`: regress each output on the past of every output (matrix A polynomial).
    - `offset`: also estimate a constant; the model's `y0` is then `y0 + A(1)^{-1} kappa`.
    - `u0`, `y0`: operating point stored in the returned model (the one `y`, `u` are relative to).

    **Returns:** `ARXResult` with the `Polynomial` model and per-output covariance.
    """
    y = jnp.asarray(y)
    u = jnp.asarray(u)
    if y.ndim != 2 or u.ndim != 2 or y.shape[0] != u.shape[0]:
        raise ModelError(f"arx_ls: y (T, ny) and u (T, nu) must share T, got {y.shape} and {u.shape}")
    if na < 0 or nb < 0 or (na == 0 and nb == 0):
        raise ModelError(f"arx_ls: impossible orders na={na}, nb={nb}")
    ny, nu = y.shape[1], u.shape[1]
    m = ny if (full_a and ny > 1) else 1
    Phi = arx_regressors(y, u, na, nb, nk, full_a=full_a)
    n0 = first_row(na, nb, as_nk(nk, ny, nu))
    n_par = Phi.shape[2] + int(bool(offset))
    if y.shape[0] - n0 <= n_par:
        raise DataError(f"arx_ls: {y.shape[0]} samples are too few for {n_par} parameters "
                         "per output")
    # the solve and the small post-processing run in NumPy: jitted or eager jnp ops would
    # compile once per shape, which dominated order searches over many candidate (na, nb)
    theta, cov, rss = _solve(Phi, y, n0, bool(offset))
    p = m * na + nu * nb
    a = theta[:, :m * na].reshape(ny, m, na)
    b = theta[:, m * na:p].reshape(ny, nu, nb)
    y0 = np.zeros(ny) if y0 is None else np.asarray(y0, np.float64)
    if offset:
        Am = np.moveaxis(a, 2, 0) if m == ny else \
            np.einsum("ik,ij->kij", a[:, 0, :], np.eye(ny))
        A1 = np.eye(ny) + Am.sum(axis=0)
        y0 = y0 + np.linalg.solve(A1, theta[:, p])
        cov = cov[:, :p, :p]
    dt = y.dtype
    model = Polynomial(a=jnp.asarray(a, dt), b=jnp.asarray(b, dt), nk=nk, ts=ts,
                       u0=None if u0 is None else jnp.asarray(u0, dt), y0=jnp.asarray(y0, dt))
    std = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0))
    return ARXResult(model=model, covariance=jnp.asarray(cov, dt), std=jnp.asarray(std, dt),
                     cost=jnp.asarray(rss.sum() / (ny * (y.shape[0] - n0)), dt))


def perturb_starts(theta0: np.ndarray, n_starts: int, seed: int, scale: float = 0.2) -> np.ndarray:
    """`(..., K, p)` start points: `theta0` itself first, then K-1 copies with relative Gaussian
    perturbations $\\theta (1 + s\\,\\xi) + 0.1 s\\, \\xi'$, deterministic from `seed`."""
    theta0 = np.asarray(theta0, dtype=np.float64)
    key = jax.random.key(int(seed))
    k1, k2 = jax.random.split(key)
    shape = theta0.shape[:-1] + (max(n_starts, 1) - 1, theta0.shape[-1])
    xi = np.asarray(jax.random.normal(k1, shape, dtype=jnp.float32), dtype=np.float64)
    xi2 = np.asarray(jax.random.normal(k2, shape, dtype=jnp.float32), dtype=np.float64)
    base = theta0[..., None, :]
    pert = base * (1.0 + scale * xi) + 0.1 * scale * xi2
    return np.concatenate([base, pert], axis=-2)


__all__ = ["ARXResult", "arx_ls", "arx_regressors", "first_row", "perturb_starts"]
