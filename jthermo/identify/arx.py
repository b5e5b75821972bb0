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
from ..models.polynomial import Polynomial, as_nk, placed


class ARXResult(eqx.Module):
    """Least-squares ARX estimate: the model and, per output, the coefficient covariance in the
    layout of `Polynomial.flat_coefficients` (`[a (m·na), b (nu·nb)]`)."""

    model: Polynomial
    covariance: Float[Array, "ny p p"]
    std: Float[Array, "ny p"]
    cost: Float[Array, ""]             # mean squared one-step prediction error


def lag_pool(y, u, na: int, L: int) -> np.ndarray:
    """Every column an ARX regression of orders up to `na`, `L` can use, `(T, k)` (NumPy):
    $-y_l(t-k)$ for each output l and k = 1..na (`ny·na`, output-major), $u_j(t-k)$ for each
    input j and k = 0..L (`nu·(L+1)`, input-major), the outputs $y_i(t)$ (`ny`) and a
    constant; samples before t = 0 are zero. Column positions: `pool_index`."""
    y = np.asarray(y, np.float64)
    u = np.asarray(u, np.float64)
    T, ny = y.shape
    Yl = -_lagged(y, na)[:, :, 1:].reshape(T, ny * na)
    Ul = _lagged(u, L).reshape(T, u.shape[1] * (L + 1))
    return np.concatenate([Yl, Ul, y, np.ones((T, 1))], axis=1)


def pool_index(ny: int, nu: int, na: int, L: int) -> dict[str, np.ndarray]:
    """Column positions in `lag_pool(y, u, na, L)`: `ylag[l, k-1]`, `ulag[j, k]`, `y[i]`,
    `one`."""
    nya = ny * na
    return {"ylag": np.arange(nya).reshape(ny, na),
            "ulag": nya + np.arange(nu * (L + 1)).reshape(nu, L + 1),
            "y": nya + nu * (L + 1) + np.arange(ny), "one": nya + nu * (L + 1) + ny}


def pool_r(pool: np.ndarray, n0: int) -> np.ndarray:
    """R of the QR factorisation of the pool's rows `n0..T-1`, `(k, k)`.

    With $X = QR$ every regression among the pool's columns, $\\min_\\theta \\|X_S\\theta -
    x_t\\|$, is the same problem on $R$: $\\|X_S\\theta - x_t\\| = \\|R_S\\theta - r_t\\|$ ($Q$ has
    orthonormal columns), so one factorisation serves every output, candidate order and
    residual cross-product, and each solve is a `(k, p)` problem instead of a `(T, p)` one."""
    return np.linalg.qr(pool[n0:], mode="r")


def pool_lstsq(R: np.ndarray, cols, target: int) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of pool column `target` on pool columns `cols` from `pool_r`'s R:
    `(theta, r)` with `r` the residual in R's coordinates ($\\|r\\|$ is the residual norm and
    $r_i^\\top r_j$ the residual cross-product of two such regressions over the same rows)."""
    A = R[:, cols]
    theta = np.linalg.lstsq(A, R[:, target], rcond=None)[0]
    return theta, R[:, target] - A @ theta


def _lagged(x: np.ndarray, L: int) -> np.ndarray:
    """`out[t, j, l] = x[t - l, j]` for `l = 0..L`, zero before `t = 0` (`filters.lagged`)."""
    T = x.shape[0]
    xp = np.concatenate([np.zeros((L,) + x.shape[1:], x.dtype), x], axis=0)
    return np.stack([xp[L - l:L - l + T] for l in range(L + 1)], axis=-1)


def _solve(R, cols, targets, n_rows):
    """Per-output least squares on the pooled rows (`pool_r`): `theta (ny, p)`, covariance
    $\\hat\\sigma_i^2 (\\Phi_i^\\top\\Phi_i)^+$ `(ny, p, p)` and residual sums of squares `(ny,)`
    (NumPy: closed-form problems, solved in milliseconds, that would otherwise compile once
    per candidate order)."""
    thetas, covs, rsss = [], [], []
    for c, t in zip(cols, targets):
        theta, r = pool_lstsq(R, c, t)
        A = R[:, c]
        rss = float(r @ r)
        sigma2 = rss / max(n_rows - len(c), 1)
        thetas.append(theta)
        covs.append(sigma2 * np.linalg.pinv(A.T @ A, hermitian=True))
        rsss.append(rss)
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
    y = np.asarray(y)
    u = np.asarray(u)
    if y.ndim != 2 or u.ndim != 2 or y.shape[0] != u.shape[0]:
        raise ModelError(f"arx_ls: y (T, ny) and u (T, nu) must share T, got {y.shape} and {u.shape}")
    if na < 0 or nb < 0 or (na == 0 and nb == 0):
        raise ModelError(f"arx_ls: impossible orders na={na}, nb={nb}")
    ny, nu = y.shape[1], u.shape[1]
    m = ny if (full_a and ny > 1) else 1
    nkt = as_nk(nk, ny, nu)
    n0 = first_row(na, nb, nkt)
    n_par = m * na + nu * nb + int(bool(offset))
    if y.shape[0] - n0 <= n_par:
        raise DataError(f"arx_ls: {y.shape[0]} samples are too few for {n_par} parameters "
                         "per output")
    # one QR of every lagged column serves all outputs (`pool_r`); the solves and the small
    # post-processing run in NumPy: jitted or eager jnp ops would compile once per shape,
    # which dominated order searches over many candidate (na, nb)
    L = max(max(r) for r in nkt) + max(nb, 1) - 1
    ix = pool_index(ny, nu, na, L)
    R = pool_r(lag_pool(y, u, na, L), n0)
    cols = [np.concatenate([ix["ylag"][:m].ravel() if m == ny else ix["ylag"][i],
                            np.concatenate([ix["ulag"][j, nkt[i][j]:nkt[i][j] + nb]
                                            for j in range(nu)]) if nb else np.zeros(0, int),
                            [ix["one"]] if offset else np.zeros(0, int)]).astype(int)
            for i in range(ny)]
    theta, cov, rss = _solve(R, cols, ix["y"], y.shape[0] - n0)
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
    model = Polynomial(a=placed(a, dt), b=placed(b, dt), nk=nk, ts=ts,
                       u0=None if u0 is None else placed(u0, dt), y0=placed(y0, dt))
    std = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0))
    return ARXResult(model=model, covariance=placed(cov, dt), std=placed(std, dt),
                     cost=placed(rss.sum() / (ny * (y.shape[0] - n0)), dt))


def perturb_starts(theta0: np.ndarray, n_starts: int, seed: int, scale: float = 0.2,
                   draws: str = "jax") -> np.ndarray:
    """`(..., K, p)` start points: `theta0` itself first, then K-1 copies with relative Gaussian
    perturbations $\\theta (1 + s\\,\\xi) + 0.1 s\\, \\xi'$, deterministic from `seed`: drawn
    by `jax.random` (`draws="jax"`, float32 normals) or by NumPy's `default_rng(seed)`
    (`draws="numpy"`: nothing to compile, other draws)."""
    theta0 = np.asarray(theta0, dtype=np.float64)
    shape = theta0.shape[:-1] + (max(n_starts, 1) - 1, theta0.shape[-1])
    if draws == "numpy":
        rng = np.random.default_rng(int(seed))
        xi, xi2 = rng.standard_normal(shape), rng.standard_normal(shape)
    else:
        k1, k2 = jax.random.split(jax.random.key(int(seed)))
        xi = np.asarray(jax.random.normal(k1, shape, dtype=jnp.float32), dtype=np.float64)
        xi2 = np.asarray(jax.random.normal(k2, shape, dtype=jnp.float32), dtype=np.float64)
    base = theta0[..., None, :]
    pert = base * (1.0 + scale * xi) + 0.1 * scale * xi2
    return np.concatenate([base, pert], axis=-2)


__all__ = ["ARXResult", "arx_ls", "first_row", "lag_pool", "perturb_starts", "pool_index",
           "pool_lstsq", "pool_r"]
