"""Exact sample-time matrices for the printer's linear part and the exponential Runge–Kutta
sub-steps (ETD2RK, Cox & Matthews 2002): $e^{Ah}$, $h\\varphi_1(Ah)$, $h\\varphi_2(Ah)$ from one
matrix exponential."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array


class PhiMatrices(eqx.Module):
    """The exponential-integrator matrices of one (sub-)step h."""

    E: Array        # e^{A h}
    P1: Array       # h φ1(A h)
    P2: Array       # h φ2(A h)


def expm_taylor(M: Array, squarings: int = 8, order: int = 14) -> Array:
    """Matrix exponential by scaling and squaring with a Taylor polynomial (fixed, branch-free:
    cheap to compile and to differentiate). Accurate to round-off for ||M|| up to ~100, far
    beyond the printer's sample-time matrices (||A Ts|| ~ 0.1–2)."""
    X = M / (2.0 ** squarings)
    eye = jnp.eye(M.shape[0], dtype=M.dtype)
    # F = e^X - I = X (I + X/2! + X^2/3! + ...), squared as (I + F)^2 = I + (2F + F^2) so that
    # the small part keeps its relative precision
    P = eye + X / (order + 1)
    for k in range(order, 1, -1):
        P = eye + (X @ P) / k
    F = X @ P
    for _ in range(squarings):
        F = 2.0 * F + F @ F
    return eye + F


def phi_matrices(A: Array, h: float) -> PhiMatrices:
    """`PhiMatrices` of $\\dot z = A z + b$ for a step `h`, from one exponential of a block matrix."""
    n = A.shape[0]
    eye = jnp.eye(n, dtype=A.dtype)
    zero = jnp.zeros((n, n), A.dtype)
    M = jnp.block([[A * h, eye * h, zero], [zero, zero, eye * h], [zero, zero, zero]])
    F = expm_taylor(M)
    return PhiMatrices(E=F[:n, :n], P1=F[:n, n:2 * n], P2=F[:n, 2 * n:] / h)

