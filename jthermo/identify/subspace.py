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
   state sequence $\\hat x(t) = \\Gamma_i^\\dagger \\mathcal O_i(t)$, one column per sample t;
5. least squares on consecutive states, $[\\hat x(t+1); y(t)] = [A\\;B; C\\;D][\\hat x(t); u(t)] +
   [\\rho_w; \\rho_v]$ (the state-sequence shift, as SIPPY does, in place of the book's
   second projection $X_{i+1} = \\underline{\\Gamma_i}^\\dagger \\mathcal O_{i-1}$), and the
   Kalman gain $K$ from the residual covariances $(Q, S, R)$ by the filter Riccati equation.

The projections are regressions between rows of the Hankel matrix, done on the Cholesky factor
of its Gram matrix (`_compress`). It runs once per fit, in NumPy/SciPy. Data are taken as
deviations from their means (or from rest, `operating_point="rest"`); the operating point is
stored in the model (`u0`, `w0`, `y0`), so `model.simulate(u)` returns absolute outputs.
The returned model is stable: eigenvalues of A outside the circle of radius
`max_radius` are pulled onto it (same angle), and K is kept only if $A - KC$ is stable.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from ..data import IOData
from ..errors import DataError, ModelError
from ..models._base import StateSpace
from ..models.polynomial import placed
from ..models.statespace import project_stable
from .operating_point import OPERATING_POINTS, known_rest_level, rest_window

WEIGHTINGS = ("cva", "moesp", "n4sid")
#: the weightings `n4sid_variants` returns by default (the state-space fit's start points)
START_WEIGHTINGS = ("cva", "moesp")
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
    return sla.lstsq(X.T, Y.T, lapack_driver="gelsy")[0].T


def _prefix_regression(L: np.ndarray, p: int, Y: np.ndarray) -> np.ndarray:
    """Coefficients c minimising ||Y - c L[:p]||_F for L lower triangular.

    The rows L[:p] vanish beyond column p, so $c = Y_{:, :p} L_{:p,:p}^{-1}$: one triangular
    solve; least squares instead when L[:p, :p] is (nearly) singular (noise-free data)."""
    Lp, Yp = L[:p, :p], Y[:, :p]
    dL = np.abs(np.diag(Lp))
    if p == 0:
        return np.zeros((Y.shape[0], 0))
    if dL.min() > 1e-10 * dL.max():
        return sla.solve_triangular(Lp, Yp.T, trans="T", lower=True).T
    return sla.lstsq(Lp.T, Yp.T, lapack_driver="gelsy")[0].T


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


def default_horizon(n: int | None, ny: int, T: int, m: int = 0) -> int:
    """Block rows of the Hankel matrices: 20, SIPPY's default (thermal systems have slow poles:
    W1 N4SID simulates 54.8 / 57.5 % at 10 block rows, 55.0 / 57.7 % at 20, N = 4 / 16 zones,
    `experiments/n4sid_horizon_check.py`), fewer when the record is short, so that the Hankel
    matrices stay at least twice as wide as tall ($j \\ge 4 i (m + n_y)$, m inputs), but always
    enough to see order `n`."""
    i = min(20, (T + 1) // (4 * (m + ny) + 2))
    if n is not None:
        i = max(i, int(np.ceil((n + 1) / ny)) + 1)
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


def _hankel_gram(s: np.ndarray, rows: int, cols: int, m: int) -> np.ndarray:
    """$H H^T$ for the block Hankel matrix H = [U; Y] of `s = [u, y] (T, d)`, u the first `m`
    channels: `rows` block rows of u, then `rows` block rows of y, `cols` columns (block row r
    holds samples r, ..., r + cols - 1).

    Block (r, q) of the lagged products is $\\sum_{t<c} s(t+r) s(t+q)^T$ with c = `cols`: the
    first block row takes one product each, the others follow along the diagonals,
    $G_{r+1,q+1} = G_{r,q} - s(r) s(q)^T + s(r+c) s(q+c)^T$: $O(\\text{rows}\\, d^2 c)$ work
    instead of the $O(\\text{rows}^2 d^2 c)$ of forming H and its product.
    """
    G = np.empty((rows, rows) + (s.shape[1],) * 2)
    head = s[:cols].T
    for q in range(rows):
        G[0, q] = head @ s[q:q + cols]
    for r in range(1, rows):
        first, last = s[r - 1], s[r - 1 + cols]
        G[r, r:] = (G[r - 1, r - 1:-1]
                    - first[None, :, None] * s[r - 1:rows - 1][:, None, :]
                    + last[None, :, None] * s[r - 1 + cols:rows - 1 + cols][:, None, :])
    upper, lower = np.triu_indices(rows, 1)
    G[lower, upper] = G[upper, lower].transpose(0, 2, 1)

    def block(a, b):   # channels a x channels b, as (rows * |a|, rows * |b|)
        g = G[:, :, a][:, :, :, b]
        return g.transpose(0, 2, 1, 3).reshape(rows * g.shape[2], rows * g.shape[3])

    u, y = slice(0, m), slice(m, None)
    return np.block([[block(u, u), block(u, y)], [block(y, u), block(y, y)]])


def _compress(us: np.ndarray, ys: np.ndarray, i: int) -> tuple[np.ndarray, np.ndarray, int]:
    """`(L, H H^T, j)`: the lower-triangular factor L of the block Hankel matrix
    H = [U_{0|2i-1}; Y_{0|2i-1}] = L Q^T (j columns) and its Gram matrix.

    Every projection below regresses rows of H on other rows of H; since Q has orthonormal
    columns these regressions (and all covariances, $H_a H_b^T = L_a L_b^T$) can be done on the
    rows of L, which is square and small, instead of on the wide Hankel matrices. L is the
    Cholesky factor of $H H^T$ (`_hankel_gram`, as in the fast N4SID of Cho, Xu & Kailath 1994)
    or, when that Gram matrix is too ill-conditioned to factor accurately (noise-free data),
    the transposed R of a QR factorisation of $H^T$.
    """
    T, m = us.shape
    ny = ys.shape[1]
    j = T - 2 * i + 1
    gram = _hankel_gram(np.concatenate([us, ys], axis=1), 2 * i, j, m)
    try:
        L = np.linalg.cholesky(gram)
        dL = np.diag(L)
        if np.all(np.isfinite(dL)) and dL.min() > 1e-5 * dL.max():
            return L, gram, j
    except np.linalg.LinAlgError:
        pass
    H = np.concatenate([_hankel(us, 0, 2 * i, j), _hankel(ys, 0, 2 * i, j)], axis=0)
    L = np.linalg.qr(H.T, mode="r").T
    return L, L @ L.T, j


def _estimate(L: np.ndarray, gram: np.ndarray, j: int, i: int, us: np.ndarray, ys: np.ndarray,
              n: int | None, weighting: str, feedthrough: bool, max_order: int | None):
    """Steps 2–5 of the module docstring on the compressed Hankel factor L (`gram` = L L^T)."""
    m, ny = us.shape[1], ys.shape[1]
    up, uf = np.arange(i * m), np.arange(i * m, 2 * i * m)
    yp, yf = 2 * i * m + np.arange(i * ny), 2 * i * m + i * ny + np.arange(i * ny)
    wp, p = np.concatenate([up, yp]), 2 * i * m + i * ny
    # oblique projection: Y_f regressed on [U_p; U_f; Y_p] (a prefix of L's rows), W_p part kept
    coef = _prefix_regression(L, p, L[yf])
    cw = np.concatenate([coef[:, up], coef[:, yp]], axis=1)             # on W_p = [U_p; Y_p]
    O = cw @ L[wp, :p]                        # rows of L vanish beyond their own index
    # Π⊥_{U_f}: M Π⊥ = M - K U_f with K = (M U_f^T)(U_f U_f^T)^{-1}, for M = Y_f and O; the
    # products with U_f are read off the Gram matrix, one solve serves both
    Gfu = gram[np.ix_(yf, uf)]
    rhs = np.concatenate([Gfu, cw @ gram[np.ix_(wp, uf)]], axis=0)
    K = sla.lstsq(gram[np.ix_(uf, uf)], rhs.T, lapack_driver="gelsy")[0].T
    Kf, Ko = K[:len(yf)], K[len(yf):]
    if weighting == "cva":
        W1, W1inv = _inv_sqrt_psd((gram[np.ix_(yf, yf)] - Kf @ Gfu.T) / j)
    else:
        W1 = W1inv = np.eye(i * ny)
    # N4SID (Van Overschee & De Moor 1996, Theorem 12: W1 = I, W2 = I) decomposes the oblique
    # projection itself; CVA and MOESP its part orthogonal to the future inputs (W2 = Π⊥)
    Operp = O if weighting == "n4sid" else O - Ko @ L[uf, :p]
    # left singular vectors and values of the wide W1 O Π⊥ = R^T Q^T: those of the square R^T
    Uo, s, _ = np.linalg.svd(np.linalg.qr((W1 @ Operp).T / np.sqrt(j), mode="r").T)
    if weighting == "cva":
        s = np.minimum(s, 1.0)   # canonical correlations
    if n is None:
        n = choose_order(s, max_order=max_order if max_order is not None
                         else min(len(s) - 1, 4 * ny + 8))
    n = int(n)
    G = W1inv @ Uo[:, :n] * np.sqrt(np.maximum(s[:n], 1e-300))      # Γ_i, (i ny, n)
    # the state sequence in time, X[:, t] = x(t + i): Γ_i^† times each past window's projection
    Wp = np.concatenate([_hankel(us, 0, i, j), _hankel(ys, 0, i, j)], axis=0)
    X = (np.linalg.pinv(G) @ cw) @ Wp
    Ui, Yi = us[i:i + j - 1].T, ys[i:i + j - 1].T
    X0, X1 = X[:, :-1], X[:, 1:]
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
    k = rw.shape[1]
    Q, S, R = rw @ rw.T / k, rw @ rv.T / k, rv @ rv.T / k
    return A, B, C, D, Q, S, R, s


def _prepare(data: IOData, n: int | None, horizon: int | None, operating_point: str = "mean",
             rest_level=None):
    u = np.asarray(data.u, dtype=np.float64)
    y = np.asarray(data.y, dtype=np.float64)
    w = np.asarray(data.w, dtype=np.float64)
    T, nu, ny = y.shape[0], u.shape[1], y.shape[1]
    if n is not None and (int(n) != n or n < 1):
        raise ModelError(f"n4sid: order n must be a positive integer, got {n!r}")
    # a constant measured signal (e.g. a nominal ambient) carries no information: its Bw
    # column is set to zero rather than estimated
    active = np.flatnonzero(w.std(0) > 0) if w.shape[1] else np.zeros(0, int)
    nw_all = w.shape[1]
    w = w[:, active]
    m = nu + w.shape[1]
    i = default_horizon(n, ny, T, m) if horizon is None else int(horizon)
    if i < 2:
        raise ModelError(f"n4sid: horizon must be >= 2, got {horizon}")
    if n is not None and n > i * ny:
        raise ModelError(f"n4sid: order {n} exceeds horizon*ny = {i * ny}; raise `horizon`")
    j = T - 2 * i + 1
    if j < 2 * i * (m + ny) + 1:
        raise DataError(f"n4sid: {T} samples are too few for horizon {i} "
                        f"(need at least {2 * i * (m + ny) + 2 * i})")
    # deviations from the operating point, each channel scaled to unit std (conditioning)
    if operating_point == "rest":
        # the record starts at rest with zero input (a cold start): u0 = 0, y0 = y(0) here,
        # refined by `_refine_rest_level`
        u0, w0 = np.zeros(nu), w[0]
        y0 = y[0] if rest_level is None else known_rest_level(rest_level, ny)
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


def _refine_rest_level(us, ys, scaling, i, n, feedthrough, max_order):
    """Output level of a record that starts at rest, from more than its first sample.

    `_prepare` takes $y_0 = y(0)$, which carries the full measurement noise. A first subspace
    estimate (horizon at most 5 when the order is given) simulates the response to the first
    M = 1 % of the samples (1 to 100) from rest, and the level moves by the mean of what it
    leaves, $\\delta = \\frac{1}{M}\\sum_{t<M}(\\tilde y(t) - \\hat y(t))$ (scaled units);
    noise-free data give δ = 0.
    """
    T, ny = ys.shape
    M = rest_window(T)
    if M == 1:
        return ys, scaling
    i1 = i if n is None else min(i, max(5, int(np.ceil((n + 1) / ny)) + 1))
    L, gram, j = _compress(us, ys, i1)
    A, B, C, D = _estimate(L, gram, j, i1, us, ys, n, "cva", feedthrough, max_order)[:4]
    x, resid = np.zeros(A.shape[0]), np.empty((M, ny))
    for t in range(M):
        resid[t] = ys[t] - C @ x - D @ us[t]
        x = A @ x + B @ us[t]
    delta = resid.mean(axis=0)
    if not np.all(np.isfinite(delta)):
        return ys, scaling
    u0, w0, y0, su, sy, *rest = scaling
    return ys - delta, (u0, w0, y0 + sy * delta, su, sy, *rest)


def _assemble(parts, scaling, ts, max_radius):
    A, Bs, C, Ds, Q, S, R = parts
    u0, w0, y0, su, sy, nu, active, nw_all = scaling
    A = project_stable(A, max_radius)
    K = _kalman_gain(A, C, Q, S, R)
    # undo the scaling: y = sy ỹ, ũ = u / su
    Bfull = Bs / su[None, :]
    Bw = np.zeros((A.shape[0], nw_all))
    Bw[:, active] = Bfull[:, nu:]
    # every array placed by a transfer (`placed`): jnp.asarray / jnp.zeros in the constructor
    # would compile a small program per shape in a fresh process
    parts = (A, Bfull[:, :nu], sy[:, None] * C, (sy[:, None] * Ds / su[None, :])[:, :nu],
             K / sy[None, :])
    return StateSpace(*(placed(x, np.float64) for x in parts), ts=ts,
                      Bw=placed(Bw, np.float64), u0=placed(u0, np.float64),
                      w0=placed(w0, np.float64), y0=placed(y0, np.float64))


def n4sid(data: IOData, n: int | None = None, horizon: int | None = None, *,
          weighting: str = "cva", feedthrough: bool = False, max_order: int | None = None,
          max_radius: float = MAX_RADIUS, operating_point: str = "mean", rest_level=None
          ) -> tuple[StateSpace, np.ndarray]:
    """Subspace estimate of an innovations state space, and the Hankel singular values.

    $x_{k+1} = A x_k + B \\tilde u_k + B_w \\tilde w_k + K e_k$, $y_k = y_0 + C x_k + D\\tilde u_k + e_k$
    (Van Overschee & De Moor 1996, Algorithm 2 of §4.3, with CVA or MOESP weighting).

    **Arguments:**
    - `data`: estimation data; measured signals `w` are treated as extra inputs (→ `Bw`).
    - `n`: state order; `None` chooses it with `choose_order` from the singular values.
    - `horizon`: block rows of the past and future Hankel matrices (default `default_horizon`).
    - `weighting`: `"cva"` (canonical variate analysis), `"moesp"` or `"n4sid"` (W1 = I and
      no projection orthogonal to the future inputs: the oblique projection itself, as
      SIPPY's N4SID).
    - `feedthrough`: estimate D (default False: thermal plants are strictly proper).
    - `max_order`: largest order `choose_order` may pick.
    - `operating_point`: `"mean"` (deviations from the data's means; the record is taken to
      sit around a steady operating point) or `"rest"` (the record starts at rest with zero
      input: `u0 = 0`, `w0 = w(0)`, `y0` the level of the first samples, see
      `_refine_rest_level`; e.g. a cold start from ambient).
    - `rest_level`: the output level at rest when it is known (a measured ambient; 0 for data
      in °C above ambient), a number or one per output; implies `operating_point="rest"`.

    **Returns:** `(model, svals)` with `model` a stable `StateSpace` at the data's operating point
    (means of u, w, y) and `svals` the singular values, largest first.
    """
    return n4sid_variants(data, n, horizon, weightings=(weighting,), feedthrough=feedthrough,
                          max_order=max_order, max_radius=max_radius,
                          operating_point=operating_point, rest_level=rest_level)[0]


def n4sid_variants(data: IOData, n: int | None, horizon: int | None = None, *,
                   weightings=START_WEIGHTINGS, feedthrough: bool = False, max_order: int | None = None,
                   max_radius: float = MAX_RADIUS, operating_point: str = "mean",
                   rest_level=None) -> list[tuple[StateSpace, np.ndarray]]:
    """`n4sid` for several weightings sharing one Hankel factorisation (multi-start points)."""
    for wt in weightings:
        if wt not in WEIGHTINGS:
            raise ModelError(f"n4sid: weighting must be one of {', '.join(WEIGHTINGS)}, got {wt!r}")
    if operating_point not in OPERATING_POINTS:
        raise ModelError(f"n4sid: operating_point must be one of {', '.join(OPERATING_POINTS)}, "
                         f"got {operating_point!r}")
    if rest_level is not None:
        operating_point = "rest"
    i, us, ys, scaling = _prepare(data, n, horizon, operating_point, rest_level)
    if operating_point == "rest" and rest_level is None:
        ys, scaling = _refine_rest_level(us, ys, scaling, i, n, feedthrough, max_order)
    L, gram, j = _compress(us, ys, i)
    out = []
    for wt in weightings:
        A, B, C, D, Q, S, R, s = _estimate(L, gram, j, i, us, ys, n, wt, feedthrough,
                                           max_order)
        out.append((_assemble((A, B, C, D, Q, S, R), scaling, data.ts, max_radius), s))
    return out


__all__ = ["WEIGHTINGS", "choose_order", "default_horizon", "n4sid", "n4sid_variants",
           "project_stable"]
