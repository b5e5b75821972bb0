"""A positive (compartmental) state space: a thermal network heat can be.

Continuous time, states the temperature rises of n nodes above the level at rest $y_0$ (the
first $n_y$ nodes are the sensors' own, the others hidden bodies such as a heater block):

$$\\dot x = A x + B u + B_w (w - w_0), \\qquad y = y_0 + C x,$$

$$A_{ik} = f_{ik} \\ (i \\ne k), \\qquad A_{kk} = -\\Big(\\sum_{i \\ne k} f_{ik} + \\ell_k\\Big),
\\qquad B = e^{\\beta}, \\qquad C = [\\operatorname{diag}(e^{\\gamma})\\;0],$$

with every heat flow $f_{ik} = e^{\\phi_{ik}}$ (node k to node i, 1/s) and leak to the
surroundings $\\ell_k = e^{\\lambda_k}$ positive. A is Metzler, and its columns are strictly
diagonally dominant ($\\mathbf 1^\\top A = -\\ell^\\top < 0$), so it is Hurwitz; every Metzler
Hurwitz matrix is a positive diagonal similarity of one of these (it has a $v > 0$ with
$v^\\top A < 0$), and that similarity keeps B, C non-negative: the parametrisation covers the
positive systems of this output structure. The measured signals' $B_w$ is free (a fan cools, the
surroundings warm). Any parameter vector gives a stable model whose impulse responses
$C e^{At} B$ are non-negative: every step response rises monotonically from zero to a
non-negative static gain $-C A^{-1} B$. The zero-order-hold discretisation (`greybox.zoh`) keeps
that: $A_d = e^{A T_s} \\ge 0$ elementwise, $B_d = \\int_0^{T_s} e^{As}ds\\,B \\ge 0$.

The parameter vector (`n_params`, `matrices`): $[\\phi$ (n(n-1) off-diagonal, row-major; none
when `coupled` is False), $\\lambda$ (n), $\\beta$ (n nu), $\\gamma$ (ny), $B_w$ (n nw)$]$.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._base import StateSpace
from .greybox import zoh


def n_params(n: int, ny: int, nu: int, nw: int, coupled: bool = True) -> int:
    """Length of the parameter vector of `matrices`."""
    return (n * (n - 1) if coupled else 0) + n + n * nu + ny + n * nw


def matrices(theta, n: int, ny: int, nu: int, nw: int, coupled: bool = True):
    """Continuous-time `(A, B, C, Bw)` of the parameter vector `theta` (module docstring);
    traceable."""
    k = 0
    off = jnp.zeros((n, n), theta.dtype)
    if coupled and n > 1:
        m = n * (n - 1)
        mask = ~np.eye(n, dtype=bool)
        off = off.at[np.nonzero(mask)].set(jnp.exp(theta[:m]))
        k = m
    leak = jnp.exp(theta[k:k + n])
    k += n
    A = off - jnp.diag(jnp.sum(off, axis=0) + leak)
    B = jnp.exp(theta[k:k + n * nu]).reshape(n, nu)
    k += n * nu
    C = jnp.zeros((ny, n), theta.dtype).at[np.arange(ny), np.arange(ny)].set(
        jnp.exp(theta[k:k + ny]))
    k += ny
    Bw = theta[k:k + n * nw].reshape(n, nw)
    return A, B, C, Bw


def discrete(theta, n: int, ny: int, nu: int, nw: int, ts, coupled: bool = True):
    """Zero-order-hold `(Ad, Bd, C, Bwd)` of `matrices` at sample time `ts`."""
    A, B, C, Bw = matrices(theta, n, ny, nu, nw, coupled)
    Ad, BB = zoh(A, jnp.concatenate([B, Bw], axis=1), ts)
    return Ad, BB[:, :nu], C, BB[:, nu:]


def statespace(theta, n: int, ny: int, nu: int, nw: int, ts: float, *, y0, w0,
               coupled: bool = True) -> StateSpace:
    """The discrete `StateSpace` of `theta`: u0 = 0 (the level `y0` is the rest with the
    heaters off), measured signals taken from `w0`."""
    Ad, Bd, C, Bwd = discrete(jnp.asarray(theta), n, ny, nu, nw, float(ts), coupled)
    dt = Ad.dtype
    return StateSpace(Ad, Bd, C, jnp.zeros((ny, nu), dt), ts=float(ts), Bw=Bwd,
                      u0=jnp.zeros(nu, dt), w0=jnp.asarray(w0, dt).reshape(nw),
                      y0=jnp.asarray(y0, dt).reshape(ny))


__all__ = ["discrete", "matrices", "n_params", "statespace"]
