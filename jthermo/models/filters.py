"""Signal filters and polynomial helpers behind the polynomial model family.

Lagged regressors, AR/FIR filters, the input path $\\sum_j B_{ij}/F_{ij}\\,u_j$ with its
written-out derivative (`rational_sum`), reflection-coefficient (Schur–Cohn) parametrisation of
monic stable polynomials, polynomial products and the per-pair input-delay layout.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Array, Float

from ..errors import ModelError

# ----------------------------------------------------------------------------- filters


def lagged(x: Float[Array, "T m"], L: int) -> Float[Array, "T m L1"]:
    """`out[t, j, l] = x[t - l, j]` for `l = 0..L`, zero before `t = 0`."""
    T = x.shape[0]
    xp = jnp.concatenate([jnp.zeros((L,) + x.shape[1:], x.dtype), x], axis=0)
    return jnp.stack([xp[L - l:L - l + T] for l in range(L + 1)], axis=-1)


def ar_filter(x: Array, den: Array) -> Array:
    """All-pole filter $y(t) = x(t) - \\sum_{k=1}^{n} den_k\\, y(t-k)$, zero initial conditions.

    `x` is `(T, *batch)`, `den` is `(*batch, n)` (the monic polynomial without its leading 1).
    A `lax.scan` over time (measured faster on CPU, with forward-mode Jacobians, than a
    log-depth prefix scan).
    """
    n = den.shape[-1]
    if n == 0:
        return x
    denT = jnp.moveaxis(den, -1, 0)                    # (n, *batch)

    def body(past, xt):                                 # past[k-1] = y(t-k)
        yt = xt - jnp.sum(denT * past, axis=0)
        return jnp.concatenate([yt[None], past[:-1]], axis=0), yt

    batch = jnp.broadcast_shapes(x.shape[1:], den.shape[:-1])
    past0 = jnp.zeros((n,) + batch, jnp.result_type(x, den))
    _, y = jax.lax.scan(body, past0, jnp.broadcast_to(x, (x.shape[0],) + batch).astype(past0.dtype))
    return y


def rational_sum(ul: Float[Array, "T nu L1"], bl: Float[Array, "nu L1"],
                 f: Float[Array, "nu nf"]) -> Float[Array, " T"]:
    """$w(t) = \\sum_j \\frac{B_j(q)}{F_j(q)} u_j(t)$ from the lagged inputs `ul[t, j, l] = u_j(t-l)`,
    the lag coefficients `bl[j, l]` of each $B_j$ and the monic denominators `f[j]` (without
    their leading 1).

    Its derivative is written out (a custom JVP), because each coefficient moves one input's
    path only (Ljung 1999, §10.3):

    $$\\frac{\\partial w}{\\partial b_{jl}} = \\frac{q^{-l} u_j}{F_j}, \\qquad
      \\frac{\\partial w}{\\partial f_{jk}} = -\\frac{q^{-k} z_j}{F_j},
      \\quad z_j = \\frac{B_j}{F_j} u_j .$$

    The filtered signals do not depend on the direction, so a forward-mode Jacobian over p
    parameters costs two filter passes instead of p (what makes OE and BJ fits of many inputs
    fast).
    """
    pairs = jnp.einsum("tjl,jl->tj", ul, bl)
    return ar_filter(pairs, f).sum(axis=1)


def _rational_sum_jvp(primals, tangents):
    ul, bl, f = primals
    dul, dbl, df = tangents
    if isinstance(dbl, SymbolicZero):
        z = ar_filter(jnp.einsum("tjl,jl->tj", ul, bl), f)         # (T, nu): B_j/F_j u_j
        dw = jnp.zeros(z.shape[:1], z.dtype)
    else:
        filtered = ar_filter(ul, f[:, None, :])                    # (T, nu, L1): u_j(t-l)/F_j
        z = jnp.einsum("tjl,jl->tj", filtered, bl)
        dw = jnp.einsum("tjl,jl->t", filtered, dbl)
    w = z.sum(axis=1)
    nf = f.shape[-1]
    if nf and not isinstance(df, SymbolicZero):
        zz = ar_filter(z, f)                                       # z_j / F_j
        dw = dw - jnp.einsum("tjk,jk->t", lagged(zz, nf)[:, :, 1:], df)
    if not isinstance(dul, SymbolicZero):
        dw = dw + ar_filter(jnp.einsum("tjl,jl->tj", dul, bl), f).sum(axis=1)
    return w, dw


rational_sum = jax.custom_jvp(rational_sum)
rational_sum.defjvp(_rational_sum_jvp, symbolic_zeros=True)


def companion_free_response(x0: Float[Array, "blocks n"], den: Float[Array, "blocks n"],
                            T: int, groups: int) -> Float[Array, "T groups"]:
    """Zero-input output of observer-canonical blocks started at `x0`, summed over `groups`
    runs of consecutive blocks: per block $x(t+1) = S x(t) - den\\, x_1(t)$ ($S$ the upward
    shift) with output $x_1(t)$, i.e. $\\mathrm{den}(q)\\, y = 0$ from the given state.
    O(blocks · n) per sample (a dense realisation costs (blocks · n)^2), and only the group
    sums are stacked over time (what a Jacobian in `x0` carries per sample)."""
    def body(x, _):
        y = x[:, 0]
        x = jnp.concatenate([x[:, 1:], jnp.zeros_like(x[:, :1])], axis=1) - den * y[:, None]
        return x, y.reshape(groups, -1).sum(axis=1)

    _, ys = jax.lax.scan(body, x0, None, length=T)
    return ys


def fir_monic(x: Array, num: Array) -> Array:
    """$y(t) = x(t) + \\sum_{k=1}^{n} num_k\\, x(t-k)$ for `x (T, *batch)`, `num (*batch, n)`."""
    n = num.shape[-1]
    if n == 0:
        return x
    T = x.shape[0]
    xp = jnp.concatenate([jnp.zeros((n,) + x.shape[1:], x.dtype), x], axis=0)
    out = x
    for k in range(1, n + 1):
        out = out + num[..., k - 1] * xp[n - k:n - k + T]
    return out


def ar_matrix_filter(w: Float[Array, "T ny"], a: Float[Array, "na ny ny"]) -> Float[Array, "T ny"]:
    """$y(t) = w(t) - \\sum_k a_k\\, y(t-k)$ with matrix coefficients (a full A polynomial)."""
    na = a.shape[0]
    if na == 0:
        return w

    def body(past, wt):
        yt = wt - jnp.einsum("kij,kj->i", a, past)
        return jnp.concatenate([yt[None], past[:-1]], axis=0), yt

    past0 = jnp.zeros((na, w.shape[1]), jnp.result_type(w, a))
    _, y = jax.lax.scan(body, past0, w.astype(past0.dtype))
    return y


# ------------------------------------------------------------- reflection coefficients


def poly_from_reflection(kappa: Array) -> Array:
    """Monic polynomial coefficients $(a_1..a_n)$ from reflection coefficients (step-up).

    Every root lies inside the unit circle iff all $|\\kappa_m| < 1$ (Schur–Cohn). Works on the
    last axis; leading axes are batch.
    """
    n = kappa.shape[-1]
    a = jnp.zeros(kappa.shape[:-1] + (0,), kappa.dtype)
    for m in range(n):
        k = kappa[..., m:m + 1]
        a = jnp.concatenate([a + k * a[..., ::-1], k], axis=-1)
    return a


def reflection_from_poly(a: Array, clip: float = 0.995) -> Array:
    """Reflection coefficients of the monic polynomial `(a_1..a_n)` (step-down), clipped to
    `|kappa| <= clip` so an unstable or marginal start maps to a nearby stable one (NumPy)."""
    a = np.array(a, dtype=np.float64)
    n = a.shape[-1]
    kap = np.zeros_like(a)
    for m in range(n, 0, -1):
        k = np.clip(a[..., m - 1], -clip, clip)
        kap[..., m - 1] = k
        prev = a[..., :m - 1]
        a = (prev - k[..., None] * prev[..., ::-1]) / (1.0 - k[..., None] ** 2)
    return kap


def stabilize(a: Array) -> np.ndarray:
    """Reflect the roots of the monic polynomial `(a_1..a_n)` outside the unit circle into it
    ($z \\to 1/\\bar z$), last axis, NumPy. Used for start points, not on fitted models."""
    a = np.asarray(a, dtype=np.float64)
    if a.shape[-1] == 0:
        return a.copy()
    flat = a.reshape(-1, a.shape[-1])
    out = np.empty_like(flat)
    for r, coeffs in enumerate(flat):
        roots = np.roots(np.concatenate([[1.0], coeffs]))
        big = np.abs(roots) >= 1.0
        roots[big] = 0.995 / np.conj(roots[big])
        out[r] = np.real(np.poly(roots))[1:]
    return out.reshape(a.shape)


def polymul(p: Array, q: Array) -> Array:
    """Product of polynomials in $q^{-1}$ (coefficient vectors starting at $q^0$), last axis."""
    n, m = p.shape[-1], q.shape[-1]
    out = jnp.zeros(jnp.broadcast_shapes(p.shape[:-1], q.shape[:-1]) + (n + m - 1,),
                    jnp.result_type(p, q))
    for k in range(m):
        out = out.at[..., k:k + n].add(p * q[..., k:k + 1])
    return out


# ------------------------------------------------------------------------------ model


def delay_onehot(nk: tuple[tuple[int, ...], ...], nb: int, L: int) -> np.ndarray:
    """`(ny, nu, nb, L+1)` selector: coefficient k of pair (i, j) sits at lag nk_ij + k."""
    ny, nu = len(nk), len(nk[0]) if nk else 0
    sel = np.zeros((ny, nu, nb, L + 1))
    for i in range(ny):
        for j in range(nu):
            for k in range(nb):
                sel[i, j, k, nk[i][j] + k] = 1.0
    return sel


def as_nk(nk, ny: int, nu: int) -> tuple[tuple[int, ...], ...]:
    """Input delays `nk` (an int, or one per output/input pair) as a `(ny, nu)` tuple of ints."""
    arr = np.asarray(nk)
    if arr.ndim == 0:
        arr = np.full((ny, nu), int(arr))
    if arr.shape != (ny, nu):
        raise ModelError(f"Polynomial: nk must be an int or a ({ny}, {nu}) array, got shape {arr.shape}")
    if np.any(arr < 0) or np.any(arr != np.round(arr)):
        raise ModelError(f"Polynomial: input delays nk must be integers >= 0, got {arr.tolist()}")
    return tuple(tuple(int(v) for v in row) for row in arr)
