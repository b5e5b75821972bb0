"""NumPy twins of the polynomial model's filters, for diagonal-A models (every ARX, ARMAX, OE
and BJ model that `fit` chooses by itself).

The JAX methods of `Polynomial` (`simulate`, `residuals`, `to_statespace`) compile once per
shape: in a fresh process that is dozens of small XLA compiles for a handful of filters over a
few thousand samples, which dominated the cold `jthermo fit` (measured by
`python benchmarks/fit_profile.py`). These functions compute the same quantities with
`scipy.signal.lfilter` on float64 arrays (equal to the JAX methods to rounding; tests/models/test_polynomial_numpy.py)
and compile nothing. Per output $i$ of a diagonal A:

$$\\hat y_i = y_{0,i} + \\frac{1}{A_i}\\sum_j \\frac{B_{ij}}{F_{ij}}\\,(u_j - u_{0,j}), \\qquad
  \\varepsilon_i = \\frac{D_i}{C_i}\\Big(A_i\\,\\tilde y_i - \\sum_j \\frac{B_{ij}}{F_{ij}}\\,\\tilde u_j\\Big).$$

The poles of the realisation `Polynomial.to_statespace()` are the roots of $A_i$, $F_{ij}$
and $D_i$ (`spectral_radius`). `initial_state` is the least-squares initial state of that
realisation: every block is in observer canonical form, so the free response of its state
$e_r$ is the impulse response of $q^{-r}/\\mathrm{den}$; an output sees only its own blocks,
so the least squares splits into one small problem per output.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from .filters import delay_onehot
from .polynomial import Polynomial


def supported(model) -> bool:
    """True for a `Polynomial` with a diagonal A (its outputs filter separately)."""
    return isinstance(model, Polynomial) and model.a.shape[1] == 1


def _parts(model: Polynomial):
    """NumPy coefficients: `a (ny, na)`, lag coefficients `bl (ny, nu, L+1)` of B (delays
    included), `c (ny, nc)`, `d (ny, nd)`, `f (ny, nu, nf)`, `u0 (nu,)`, `y0 (ny,)`."""
    b = np.asarray(model.b, np.float64)
    ny, nu, nb = b.shape
    L = max(max(r) for r in model.nk) + max(nb, 1) - 1 if ny and nu else 0
    bl = np.einsum("ijk,ijkl->ijl", b, delay_onehot(model.nk, nb, L))
    return (np.asarray(model.a, np.float64)[:, 0, :], bl, np.asarray(model.c, np.float64),
            np.asarray(model.d, np.float64), np.asarray(model.f, np.float64),
            np.asarray(model.u0, np.float64), np.asarray(model.y0, np.float64))


def _monic(coef: np.ndarray) -> np.ndarray:
    return np.concatenate([[1.0], coef])


def _input_part(bl, f, du) -> np.ndarray:
    """$\\sum_j B_{ij}/F_{ij}\\, \\tilde u_j$ per output, `(T, ny)`."""
    ny, nu = bl.shape[:2]
    out = np.zeros((du.shape[0], ny))
    for i in range(ny):
        for j in range(nu):
            out[:, i] += lfilter(bl[i, j], _monic(f[i, j]), du[:, j])
    return out


def simulate(model: Polynomial, u) -> np.ndarray:
    """`model.simulate(u)` (from rest at the operating point), `(T, ny)` NumPy."""
    a, bl, _, _, f, u0, y0 = _parts(model)
    w = _input_part(bl, f, np.asarray(u, np.float64) - u0)
    return y0 + np.stack([lfilter([1.0], _monic(a[i]), w[:, i]) for i in range(w.shape[1])], axis=1)


def residuals(model: Polynomial, y, u) -> np.ndarray:
    """`model.residuals(y, u)`: one-step prediction errors, zero initial conditions, `(T, ny)`."""
    a, bl, c, d, f, u0, y0 = _parts(model)
    dy = np.asarray(y, np.float64) - y0
    v = np.stack([lfilter(_monic(a[i]), [1.0], dy[:, i]) for i in range(dy.shape[1])], axis=1)
    v -= _input_part(bl, f, np.asarray(u, np.float64) - u0)
    return np.stack([lfilter(_monic(d[i]), _monic(c[i]), v[:, i]) for i in range(v.shape[1])],
                    axis=1)


def spectral_radius(model: Polynomial) -> float:
    """Largest pole magnitude of `model.to_statespace()`: the largest root of any $A_i$,
    $F_{ij}$, $D_i$ (0 without poles, `inf` when a coefficient is not finite)."""
    a, _, _, d, f, _, _ = _parts(model)
    polys = list(a) + list(d) + [f[i, j] for i in range(f.shape[0]) for j in range(f.shape[1])]
    if not all(np.all(np.isfinite(p)) for p in polys):
        return float("inf")
    radii = [np.max(np.abs(np.roots(_monic(p)))) for p in polys if p.size]
    return float(max(radii, default=0.0))


def step_responses(model: Polynomial, n: int) -> np.ndarray:
    """Unit-step responses of the deterministic part $B_{ij}/(A_i F_{ij})$ for k = 0..n-1,
    `(n, ny, nu)`: `Polynomial.to_statespace()`'s $s(k) = C x_k + D$, $x_{k+1} = A x_k + B$."""
    a, bl, _, _, f, _, _ = _parts(model)
    ny, nu = bl.shape[:2]
    ones = np.ones(int(n))
    out = np.empty((int(n), ny, nu))
    for i in range(ny):
        for j in range(nu):
            out[:, i, j] = lfilter(bl[i, j], np.convolve(_monic(a[i]), _monic(f[i, j])), ones)
    return out


def dc_gain(model: Polynomial) -> np.ndarray:
    """Static gains $B_{ij}(1) / (A_i(1) F_{ij}(1))$, `(ny, nu)` (of a stable model)."""
    a, bl, _, _, f, _, _ = _parts(model)
    return bl.sum(axis=2) / ((1.0 + a.sum(axis=1))[:, None] * (1.0 + f.sum(axis=2)))


def n_states(model: Polynomial) -> int:
    """State dimension of `Polynomial.to_statespace()`."""
    return _blocks(model, _parts(model))[1]


def _blocks(model: Polynomial, parts) -> tuple[list[list[np.ndarray]], int]:
    """Denominators (monic, padded to the block size) of the realisation's observer-canonical
    blocks, listed per output in state order, and the state dimension.

    With input denominators (`nf > 0`) the realisation is parallel: pair blocks $A_i F_{ij}$
    (size $\\max(L, n_a + n_f)$) for every output and input, then one noise block $A_i D_i$ per
    output (size $\\max(n_a + n_d, n_c)$). Otherwise one block $A_i D_i$ per output (size
    $\\max(n_a + n_d, n_c, L + n_d)$). See `Polynomial.to_statespace`.
    """
    a, bl, c, d, f, _, _ = parts
    ny, nu, L1 = bl.shape
    na, nc, nd, nf = a.shape[1], c.shape[1], d.shape[1], f.shape[2]
    pad = lambda p, n: np.concatenate([p, np.zeros(n + 1 - p.size)])  # noqa: E731
    if nf:
        n, m = max(L1 - 1, na + nf), max(na + nd, nc)
        pairs = [[pad(np.convolve(_monic(a[i]), _monic(f[i, j])), n) for j in range(nu)]
                 for i in range(ny)]
        noise = [[pad(np.convolve(_monic(a[i]), _monic(d[i])), m)] if m else [] for i in range(ny)]
        order = [(i, pairs[i]) for i in range(ny)] + [(i, noise[i]) for i in range(ny)]
        return order, ny * nu * n + ny * m
    n = max(na + nd, nc, L1 - 1 + nd)
    dens = [(i, [pad(np.convolve(_monic(a[i]), _monic(d[i])), n)] if n else []) for i in range(ny)]
    return dens, ny * n


def initial_state(model: Polynomial, y, u) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares initial state of `model.to_statespace()` for the data `y`, `u` and the
    simulation from it: `(x0 (nx,), yhat (T, ny))` (what `validate.compare` estimates).

    $\\hat y_i = \\hat y_i^{\\mathrm{rest}} + O_i x_{0,i}$ with $O_i$ the free responses of
    output $i$'s blocks; each output's $x_{0,i}$ by least squares on column-scaled $O_i$.
    """
    y = np.asarray(y, np.float64)
    T = y.shape[0]
    parts = _parts(model)
    ysim = simulate(model, u)
    blocks, nx = _blocks(model, parts)
    delta = np.zeros(T)
    delta[0] = 1.0
    cols: dict[int, list[np.ndarray]] = {i: [] for i in range(y.shape[1])}
    for i, dens in blocks:
        for den in dens:
            h = lfilter([1.0], den, delta)
            n = den.size - 1
            cols[i].append(np.stack([np.concatenate([np.zeros(r), h[:T - r]]) for r in range(n)],
                                    axis=1))
    # state order of the realisation: the blocks as listed, each output's share in turn
    x_parts, yhat = [None] * len(blocks), ysim.copy()
    taken = {i: 0 for i in cols}
    solved = {}
    for i, c in cols.items():
        if not c:
            continue
        O = np.concatenate(c, axis=1)
        scale = np.sqrt(np.sum(O ** 2, axis=0))
        scale = np.where(scale > 0, scale, 1.0)
        dx = np.linalg.lstsq(O / scale, y[:, i] - ysim[:, i], rcond=None)[0] / scale
        yhat[:, i] += O @ dx
        solved[i] = dx
    for k, (i, dens) in enumerate(blocks):
        n_i = sum(den.size - 1 for den in dens)
        x_parts[k] = solved[i][taken[i]:taken[i] + n_i] if n_i else np.zeros(0)
        taken[i] += n_i
    return (np.concatenate(x_parts) if x_parts else np.zeros(nx)), yhat


__all__ = ["dc_gain", "initial_state", "n_states", "residuals", "simulate", "spectral_radius",
           "step_responses", "supported"]
