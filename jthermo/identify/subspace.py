"""Subspace identification (N4SID family): a non-iterative start for state-space PEM.

The combined deterministic–stochastic algorithm of Van Overschee & De Moor (1996, §4.3,
"Algorithm 2"), with CVA weighting (Larimore 1990) by default or MOESP weighting
(Verhaegen 1994):

1. block Hankel matrices of the past $W_p = [U_p; Y_p]$ and the future $U_f, Y_f$
   (`horizon` block rows each);
2. the oblique projection $\\mathcal O_i = Y_f /_{U_f} W_p$ (least squares on $[W_p; U_f]$);
3. the SVD of $W_1 \\mathcal O_i \\Pi^\\perp_{U_f}$, whose singular values (the Hankel singular
   values; canonical correlations for CVA) show the order;
4. the extended observability matrix $\\Gamma_i = W_1^{-1} U_1 S_1^{1/2}$ and the Kalman-filter
   state sequences $X_i = \\Gamma_i^\\dagger \\mathcal O_i$,
   $X_{i+1} = \\underline{\\Gamma_i}^\\dagger \\mathcal O_{i-1}$;
5. least squares $[X_{i+1}; Y_{i|i}] = [A\\;B; C\\;D][X_i; U_{i|i}] + [\\rho_w; \\rho_v]$, and the
   Kalman gain $K$ from the residual covariances $(Q, S, R)$ by the filter Riccati equation.

It runs once per fit, in NumPy/SciPy. Data are taken as deviations from their mean; the means
are stored as the model's operating point (`u0`, `w0`, `y0`), so `model.simulate(u)` returns
absolute outputs. The returned model is stable: eigenvalues of A outside the circle of radius
`max_radius` are pulled onto it (same angle), and K is kept only if $A - KC$ is stable.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from ..data import IOData
from ..errors import DataError, ModelError
from ..models._base import StateSpace
from ..models.statespace import project_stable

WEIGHTINGS = ("cva", "moesp")
OPERATING_POINTS = ("mean", "rest")
#: eigenvalues of the returned A lie inside this radius
MAX_RADIUS = 0.9995


def _hankel(s: np.ndarray, first: int, rows: int, cols: int) -> np.ndarray:
    """Block Hankel matrix with block rows `first..first+rows-1` of `s (T, m)`: `(rows*m, cols)`."""
    return np.concatenate([s[first + r:first + r + cols].T for r in range(rows)], axis=0) \
        if rows > 0 else np.zeros((0, cols))


def _lstsq_right(Y: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Coefficients L minimising ||Y - L X||_F (rows are signals, columns samples)."""
    if X.shape[0] == 0:
        return np.zeros((Y.shape[0], 0))
    return np.linalg.lstsq(X.T, Y.T, rcond=None)[0].T


def _perp(M: np.ndarray, U: np.ndarray) -> np.ndarray:
    """$M \\Pi^\\perp_U$: the part of the rows of M orthogonal to the row space of U."""
    if U.shape[0] == 0:
        return M
    return M - _lstsq_right(M, U) @ U


def _oblique(Yf: np.ndarray, Uf: np.ndarray, Wp: np.ndarray) -> np.ndarray:
    """Oblique projection $Y_f /_{U_f} W_p$: the $W_p$ part of the regression of Y_f on [W_p; U_f]."""
    L = _lstsq_right(Yf, np.concatenate([Wp, Uf], axis=0))
    return L[:, :Wp.shape[0]] @ Wp


def _inv_sqrt_psd(M: np.ndarray, rel_floor: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """$M^{-1/2}$ and $M^{1/2}$ of a symmetric PSD matrix, eigenvalues floored."""
    lam, V = np.linalg.eigh(0.5 * (M + M.T))
    lam = np.maximum(lam, rel_floor * max(float(lam.max()), 1e-300))
    return (V / np.sqrt(lam)) @ V.T, (V * np.sqrt(lam)) @ V.T


def choose_order(svals, max_order: int | None = None) -> int:
    """Model order from the Hankel singular values: the largest gap in $\\log \\sigma_k$.

    $\\hat n = \\arg\\max_k (\\log\\sigma_k - \\log\\sigma_{k+1})$, k = 1..`max_order`, a common
    default (the MATLAB `n4sid` order plot marks the same gap). Singular values below
    $10^{-12}\\sigma_1$ are treated as zero, so a noise-free system gives its exact order.
    """
    s = np.asarray(svals, dtype=np.float64).ravel()
    if s.size < 2 or not np.all(np.isfinite(s)) or s[0] <= 0:
        raise ModelError("choose_order: need at least two finite singular values")
    s = np.maximum(s, 1e-12 * s[0])
    gaps = np.log(s[:-1]) - np.log(s[1:])
    kmax = len(gaps) if max_order is None else max(1, min(int(max_order), len(gaps)))
    return int(np.argmax(gaps[:kmax])) + 1


def default_horizon(n: int | None, ny: int, T: int) -> int:
    """Block rows: 10 (thermal systems have slow poles), at least enough to see order `n`."""
    i = 10
    if n is not None:
        i = max(i, int(np.ceil((n + 1) / ny)) + 1)
    # keep the Hankel matrices wider than tall
    return int(max(2, min(i, (T + 1) // 4)))


def _kalman_gain(A, C, Q, S, R):
    """Steady-state Kalman (predictor) gain $K = (A P C^T + S)(C P C^T + R)^{-1}$."""
    nx, ny = A.shape[0], C.shape[0]
    scale = max(float(np.trace(R)) / max(ny, 1), 1e-300)
    R = 0.5 * (R + R.T) + 1e-10 * scale * np.eye(ny)
    cands = []
    try:
        P = sla.solve_discrete_are(A.T, C.T, 0.5 * (Q + Q.T), R, s=S)
        cands.append((A @ P @ C.T + S) @ np.linalg.inv(C @ P @ C.T + R))
    except (np.linalg.LinAlgError, ValueError):
        pass
    cands.append(S @ np.linalg.inv(R))   # states are Kalman-filter states: w ≈ K e
    for K in cands:
        if np.all(np.isfinite(K)) and np.max(np.abs(np.linalg.eigvals(A - K @ C))) < 1.0:
            return K
    return np.zeros((nx, ny))


def _compress(us: np.ndarray, ys: np.ndarray, i: int) -> tuple[np.ndarray, int]:
    """Lower-triangular factor L of the block Hankel matrix H = [U_{0|2i-1}; Y_{0|2i-1}] = L Q^T.

    Every projection below regresses rows of H on other rows of H; since Q has orthonormal
    columns these regressions (and all covariances, $H_a H_b^T = L_a L_b^T$) can be done on the
    rows of L, which is square and small, instead of on the wide Hankel matrices.
    """
    T = us.shape[0]
    j = T - 2 * i + 1
    H = np.concatenate([_hankel(us, 0, 2 * i, j), _hankel(ys, 0, 2 * i, j)], axis=0)
    R = np.linalg.qr(H.T, mode="r")
    return R.T, j


def _estimate(L: np.ndarray, j: int, i: int, m: int, ny: int, n: int | None, weighting: str,
              feedthrough: bool, max_order: int | None):
    """Algorithm 2 of Van Overschee & De Moor (1996) on the compressed Hankel factor L."""

    def u_rows(first, count):
        return L[first * m:(first + count) * m]

    def y_rows(first, count):
        off = 2 * i * m
        return L[off + first * ny:off + (first + count) * ny]

    Up, Uf = u_rows(0, i), u_rows(i, i)
    Yp, Yf = y_rows(0, i), y_rows(i, i)
    Wp = np.concatenate([Up, Yp], axis=0)
    O = _oblique(Yf, Uf, Wp)
    if weighting == "cva":
        Yperp = _perp(Yf, Uf)
        W1, W1inv = _inv_sqrt_psd(Yperp @ Yperp.T / j)
    else:
        W1 = W1inv = np.eye(i * ny)
    Uo, s, _ = np.linalg.svd(W1 @ _perp(O, Uf) / np.sqrt(j), full_matrices=False)
    if weighting == "cva":
        s = np.minimum(s, 1.0)   # canonical correlations
    if n is None:
        n = choose_order(s, max_order=max_order if max_order is not None
                         else min(len(s) - 1, 4 * ny + 8))
    n = int(n)
    G = W1inv @ Uo[:, :n] * np.sqrt(np.maximum(s[:n], 1e-300))      # Γ_i, (i ny, n)
    X0 = np.linalg.pinv(G) @ O                                        # X_i   (compressed)
    Wp1 = np.concatenate([u_rows(0, i + 1), y_rows(0, i + 1)], axis=0)
    O1 = _oblique(y_rows(i + 1, i - 1), u_rows(i + 1, i - 1), Wp1)
    X1 = np.linalg.pinv(G[:-ny]) @ O1                                 # X_{i+1}
    Ui, Yi = u_rows(i, 1), y_rows(i, 1)
    Z = np.concatenate([X0, Ui], axis=0)
    AB = _lstsq_right(X1, Z)
    A, B = AB[:, :n], AB[:, n:]
    if feedthrough:
        CD = _lstsq_right(Yi, Z)
        C, D = CD[:, :n], CD[:, n:]
    else:
        C = _lstsq_right(Yi, X0)
        D = np.zeros((ny, m))
    rw = X1 - A @ X0 - B @ Ui
    rv = Yi - C @ X0 - D @ Ui
    Q, S, R = rw @ rw.T / j, rw @ rv.T / j, rv @ rv.T / j
    return A, B, C, D, Q, S, R, s


def _prepare(data: IOData, n: int | None, horizon: int | None, operating_point: str = "mean"):
    u = np.asarray(data.u, dtype=np.float64)
    y = np.asarray(data.y, dtype=np.float64)
    w = np.asarray(data.w, dtype=np.float64)
    T, nu, ny = y.shape[0], u.shape[1], y.shape[1]
    if n is not None and (int(n) != n or n < 1):
        raise ModelError(f"n4sid: order n must be a positive integer, got {n!r}")
    i = default_horizon(n, ny, T) if horizon is None else int(horizon)
    if i < 2:
        raise ModelError(f"n4sid: horizon must be >= 2, got {horizon}")
    if n is not None and n > i * ny:
        raise ModelError(f"n4sid: order {n} exceeds horizon*ny = {i * ny}; raise `horizon`")
    # a constant measured signal (e.g. a nominal ambient) carries no information: its Bw
    # column is set to zero rather than estimated
    active = np.flatnonzero(w.std(0) > 0) if w.shape[1] else np.zeros(0, int)
    nw_all = w.shape[1]
    w = w[:, active]
    m = nu + w.shape[1]
    j = T - 2 * i + 1
    if j < 2 * i * (m + ny) + 1:
        raise DataError(f"n4sid: {T} samples are too few for horizon {i} "
                        f"(need at least {2 * i * (m + ny) + 2 * i})")
    # deviations from the operating point, each channel scaled to unit std (conditioning)
    if operating_point == "rest":
        # the record starts at rest with zero input (a cold start): u0 = 0, y0 = y(0)
        u0, w0, y0 = np.zeros(nu), w[0], y[0]
        w0_all = np.asarray(data.w, dtype=np.float64)[0]
    else:
        u0, w0, y0 = u.mean(0), w.mean(0), y.mean(0)
        w0_all = np.asarray(data.w, dtype=np.float64).mean(0)
    uw = np.concatenate([u - u0, w - w0], axis=1)
    su, sy = uw.std(0), (y - y0).std(0)
    if np.any(su == 0):
        raise DataError("n4sid: an input is constant: it cannot excite the system")
    if np.any(sy == 0):
        raise DataError("n4sid: an output is constant: nothing to identify")
    return i, uw / su, (y - y0) / sy, (u0, w0_all, y0, su, sy, nu, active, nw_all)


def _assemble(parts, scaling, ts, max_radius):
    A, Bs, C, Ds, Q, S, R = parts
    u0, w0, y0, su, sy, nu, active, nw_all = scaling
    A = project_stable(A, max_radius)
    K = _kalman_gain(A, C, Q, S, R)
    # undo the scaling: y = sy ỹ, ũ = u / su
    Bfull = Bs / su[None, :]
    Bw = np.zeros((A.shape[0], nw_all))
    Bw[:, active] = Bfull[:, nu:]
    return StateSpace(A, Bfull[:, :nu], sy[:, None] * C, (sy[:, None] * Ds / su[None, :])[:, :nu],
                      K / sy[None, :], ts=ts, Bw=Bw if nw_all else None, u0=u0, w0=w0, y0=y0)


def n4sid(data: IOData, n: int | None = None, horizon: int | None = None, *,
          weighting: str = "cva", feedthrough: bool = False, max_order: int | None = None,
          max_radius: float = MAX_RADIUS, operating_point: str = "mean"
          ) -> tuple[StateSpace, np.ndarray]:
    """Subspace estimate of an innovations state space, and the Hankel singular values.

    $x_{k+1} = A x_k + B \\tilde u_k + B_w \\tilde w_k + K e_k$, $y_k = y_0 + C x_k + D\\tilde u_k + e_k$
    (Van Overschee & De Moor 1996, Algorithm 2 of §4.3, with CVA or MOESP weighting).

    **Arguments:**
    - `data`: estimation data; measured signals `w` are treated as extra inputs (→ `Bw`).
    - `n`: state order; `None` chooses it with `choose_order` from the singular values.
    - `horizon`: block rows of the past and future Hankel matrices (default `default_horizon`).
    - `weighting`: `"cva"` (canonical variate analysis) or `"moesp"`.
    - `feedthrough`: estimate D (default False: thermal plants are strictly proper).
    - `max_order`: largest order `choose_order` may pick.
    - `operating_point`: `"mean"` (deviations from the data's means; the record is taken to
      sit around a steady operating point) or `"rest"` (the record starts at rest with zero
      input: `u0 = 0`, `w0 = w(0)`, `y0 = y(0)`, e.g. a cold start from ambient).

    **Returns:** `(model, svals)` with `model` a stable `StateSpace` at the data's operating point
    (means of u, w, y) and `svals` the singular values, largest first.
    """
    return n4sid_variants(data, n, horizon, weightings=(weighting,), feedthrough=feedthrough,
                          max_order=max_order, max_radius=max_radius,
                          operating_point=operating_point)[0]


def n4sid_variants(data: IOData, n: int | None, horizon: int | None = None, *,
                   weightings=WEIGHTINGS, feedthrough: bool = False, max_order: int | None = None,
                   max_radius: float = MAX_RADIUS, operating_point: str = "mean"
                   ) -> list[tuple[StateSpace, np.ndarray]]:
    """`n4sid` for several weightings sharing one Hankel factorisation (multi-start points)."""
    for wt in weightings:
        if wt not in WEIGHTINGS:
            raise ModelError(f"n4sid: weighting must be one of {', '.join(WEIGHTINGS)}, got {wt!r}")
    if operating_point not in OPERATING_POINTS:
        raise ModelError(f"n4sid: operating_point must be one of {', '.join(OPERATING_POINTS)}, "
                         f"got {operating_point!r}")
    i, us, ys, scaling = _prepare(data, n, horizon, operating_point)
    L, j = _compress(us, ys, i)
    out = []
    for wt in weightings:
        A, B, C, D, Q, S, R, s = _estimate(L, j, i, us.shape[1], ys.shape[1], n, wt,
                                           feedthrough, max_order)
        out.append((_assemble((A, B, C, D, Q, S, R), scaling, data.ts, max_radius), s))
    return out


__all__ = ["WEIGHTINGS", "choose_order", "default_horizon", "n4sid", "n4sid_variants", "project_stable"]
