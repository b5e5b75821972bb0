"""The diagnosis models' state recurrence, with a forward-mode derivative that batches well.

Every model of the mechanism library (`mechanisms.py`) is, after its exact zero-order-hold
discretisation, the recurrence

$$ s_{k+1} = E s_k + P q(x_k) + f_k, \\qquad q(x) = a\\,x - r\\big((x + 273.15)^4 - \\sigma_k\\big),
\\qquad x_k = s_k[{:}n], $$

with $m$ states of which the first $n$ are zone temperatures (°C) that radiate (`a`, `r`,
`sigma` as in `mechanisms.loss_split`). Its output is $x_0 \\dots x_{T-1}$.

The Levenberg–Marquardt fits need its Jacobian with respect to tens of parameters by forward
mode. Differentiating the scan body as written costs, per step and per tangent, the tangent of
every product in the body; here the tangents $\\dot s$ obey the *linear* recurrence

$$ \\dot s_{k+1} = A_k \\dot s_k + g_k, \\qquad A_k = E + P\\,\\mathrm{diag}(a - 4 r (x_k + 273.15)^3),$$
$$ g_k = \\dot E s_k + \\dot P q_k + P\\big(\\dot a\\,x_k - \\dot r((x_k + 273.15)^4 - \\sigma_k)
+ r \\dot\\sigma_k\\big) + \\dot f_k, $$

whose inputs $g_k$ are computed for all $k$ at once, outside the loop, so that the loop body is
one matrix product $A_k \\dot S$ for all tangents $\\dot S$ together (under `jax.vmap`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

#: °C → K
KELVIN = 273.15
#: scan unrolling of the primal and the tangent loops
UNROLL = 4


def _states(E, P, a, r, F, sig, s0):
    """Primal pass: the states $s_0 \\dots s_{T-1}$ `(T, m)`."""
    n = a.shape[0]

    def body(s, inp):
        fk, sk = inp
        x = s[:n]
        q = a * x - r * ((x + KELVIN) ** 4 - sk)
        return E @ s + P @ q + fk, s

    return jax.lax.scan(body, s0, (F, sig), unroll=UNROLL)[1]


@jax.custom_jvp
def radiative(E, P, a, r, F, sig, s0):
    """Zone temperatures $x_0 \\dots x_{T-1}$ `(T, n)` of the recurrence above.

    **Arguments:** `E (m, m)`, `P (m, n)`, `a, r (n,)`, `F (T, m)` the inputs $f_k$,
    `sig (T, n)` $\\sigma_k = (T_{s,k} + 273.15)^4$, `s0 (m,)`."""
    return _states(E, P, a, r, F, sig, s0)[:, : a.shape[0]]


@radiative.defjvp
def _radiative_jvp(primals, tangents):
    E, P, a, r, F, sig, s0 = primals
    dE, dP, da, dr, dF, dsig, ds0 = tangents
    n, m = a.shape[0], E.shape[0]
    S = _states(E, P, a, r, F, sig, s0)
    X = S[:, :n]
    x4 = (X + KELVIN) ** 4 - sig
    Q = a * X - r * x4
    C = a - 4.0 * r * (X + KELVIN) ** 3                                   # dq/dx, (T, n)
    A = E[None] + jnp.concatenate([P[None] * C[:, None, :], jnp.zeros((X.shape[0], m, m - n), E.dtype)],
                                  axis=2)
    G = S @ dE.T + Q @ dP.T + (da * X - dr * x4 + r * dsig) @ P.T + dF

    def body(ds, inp):
        Ak, gk = inp
        return Ak @ ds + gk, ds[:n]

    dX = jax.lax.scan(body, ds0, (A, G), unroll=UNROLL)[1]
    return X, dX


__all__ = ["radiative"]
