"""Parametrised innovations state space for prediction-error estimation.

$$x_{k+1} = A x_k + B \\tilde u_k + B_w \\tilde w_k + K e_k, \\qquad
  y_k = y_0 + C x_k + D \\tilde u_k + e_k$$

(Ljung 1999, §4.3). The free parameters are the array leaves `A`, `B`, `Bw`, `K` and, unless
the output matrix is fixed, `C`. When $n \\ge n_y$ and C has full row rank the estimator works in
the basis where $C = [I_{n_y}\\;0]$ (`InnovationsSS.canonical`): a similarity transform that removes
$n_y n$ of the $n^2$ redundant directions of the full parametrisation (all of them when
$n = n_y$, the usual multi-zone case: one state per zone). The parameter vector used by PEM is
`pack(model)`; `unpack(theta, template)` is its inverse.

Stability: the PEM predictor needs $A - KC$ stable and the returned model needs A stable; the
fit projects A's eigenvalues inside the unit circle (`stabilized`) before returning.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ModelError
from ._base import AbstractModel, StateSpace


class InnovationsSS(AbstractModel):
    """Innovations-form state space whose array leaves are the PEM parameters.

    **Fields:**
    - `A (nx, nx)`, `B (nx, nu)`, `C (ny, nx)`, `K (nx, ny)`, `Bw (nx, nw)`: free parameters
      (C is held fixed when `fixed_c`; K is held at zero when `output_error`).
    - `D (ny, nu)`: feedthrough, zero for thermal plants (not estimated).
    - `u0`, `w0`, `y0`: operating point (power fraction, signal units, °C); not estimated.
    - `ts`: sample time in s. `fixed_c`, `output_error`: structure flags (static).
    """

    A: Float[Array, "nx nx"]
    B: Float[Array, "nx nu"]
    C: Float[Array, "ny nx"]
    K: Float[Array, "nx ny"]
    Bw: Float[Array, "nx nw"]
    D: Float[Array, "ny nu"]
    u0: Float[Array, " nu"]
    w0: Float[Array, " nw"]
    y0: Float[Array, " ny"]
    ts_: float = eqx.field(static=True)
    fixed_c: bool = eqx.field(static=True, default=False)
    output_error: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        nx = self.A.shape[0]
        ny, nu = self.C.shape[0], self.B.shape[1]
        want = {"A": (nx, nx), "B": (nx, nu), "C": (ny, nx), "K": (nx, ny),
                "Bw": (nx, self.Bw.shape[1]), "D": (ny, nu)}
        for name, shape in want.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ModelError(f"InnovationsSS: `{name}` has shape {getattr(self, name).shape}, "
                                 f"expected {shape}")

    @staticmethod
    def from_statespace(ss: StateSpace, *, canonical: bool = True,
                        output_error: bool = False) -> InnovationsSS:
        """Wrap a `StateSpace`; with `canonical`, change basis so that $C = [I\\;0]$ when possible."""
        A, B, C, K, Bw = (np.asarray(m, dtype=np.float64) for m in (ss.A, ss.B, ss.C, ss.K, ss.Bw))
        nx, ny = A.shape[0], C.shape[0]
        fixed = False
        if canonical and nx >= ny and np.linalg.matrix_rank(C) == ny:
            # T = [C; N^T] with N an orthonormal basis of null(C): C T^{-1} = [I 0]
            _, _, Vt = np.linalg.svd(C)
            Tm = np.concatenate([C, Vt[ny:]], axis=0)
            if np.linalg.cond(Tm) < 1e10:
                Ti = np.linalg.inv(Tm)
                A, B, K, Bw, C = Tm @ A @ Ti, Tm @ B, Tm @ K, Tm @ Bw, np.eye(ny, nx)
                fixed = True
        if output_error:
            K = np.zeros_like(K)
        dt = jnp.asarray(ss.A).dtype
        j = lambda a: jnp.asarray(a, dt)
        return InnovationsSS(A=j(A), B=j(B), C=j(C), K=j(K), Bw=j(Bw), D=jnp.asarray(ss.D),
                             u0=jnp.asarray(ss.u0), w0=jnp.asarray(ss.w0), y0=jnp.asarray(ss.y0),
                             ts_=ss.ts, fixed_c=fixed, output_error=output_error)

    @property
    def ts(self) -> float:
        return self.ts_

    def to_statespace(self) -> StateSpace:
        return StateSpace(self.A, self.B, self.C, self.D, self.K, ts=self.ts_, Bw=self.Bw,
                          u0=self.u0, w0=self.w0, y0=self.y0)

    def free_leaves(self) -> tuple[Array, ...]:
        """The estimated arrays, in `pack` order."""
        leaves = [self.A, self.B]
        if not self.fixed_c:
            leaves.append(self.C)
        if not self.output_error:
            leaves.append(self.K)
        leaves.append(self.Bw)
        return tuple(leaves)

    def n_params(self) -> int:
        return int(sum(a.size for a in self.free_leaves()))

    def stabilized(self, max_radius: float = 0.9995) -> InnovationsSS:
        """This model with A's eigenvalues pulled inside `max_radius` (NumPy; not traced)."""
        A = project_stable(np.asarray(self.A), max_radius)
        return eqx.tree_at(lambda m: m.A, self, jnp.asarray(A, self.A.dtype))


def project_stable(A: np.ndarray, max_radius: float = 0.9995) -> np.ndarray:
    """A with every eigenvalue of modulus > `max_radius` moved radially onto that circle.

    Uses the eigendecomposition $A = V \\Lambda V^{-1}$; complex pairs are moved together so the
    result is real. A matrix already inside is returned unchanged.
    """
    A = np.asarray(A, dtype=np.float64)
    lam, V = np.linalg.eig(A)
    mag = np.abs(lam)
    if A.size == 0 or mag.max() <= max_radius:
        return A
    lam2 = np.where(mag > max_radius, lam / mag * max_radius, lam)
    A2 = (V * lam2) @ np.linalg.inv(V)
    return np.real(A2)


def pack(model: InnovationsSS) -> Float[Array, " p"]:
    """The free parameters of `model` as one flat vector."""
    return jnp.concatenate([jnp.ravel(a) for a in model.free_leaves()])


def unpack(theta: Float[Array, " p"], template: InnovationsSS) -> InnovationsSS:
    """Inverse of `pack`: `template` with its free leaves read from `theta` (traceable)."""
    leaves = template.free_leaves()
    sizes = [a.size for a in leaves]
    if theta.shape != (sum(sizes),):
        raise ModelError(f"unpack: theta has shape {theta.shape}, expected ({sum(sizes)},)")
    parts, k = [], 0
    for a in leaves:
        parts.append(jnp.reshape(theta[k:k + a.size], a.shape))
        k += a.size

    def where(m):
        return m.free_leaves()

    return eqx.tree_at(where, template, tuple(parts))


def innovations(model: InnovationsSS | StateSpace, y: Float[Array, "T ny"], du: Float[Array, "T nu"],
                dw: Float[Array, "T nw"], x0: Float[Array, " nx"] | None = None) -> Float[Array, "T ny"]:
    """One-step prediction errors of the innovations predictor, from deviations `du`, `dw`.

    $\\hat x_{k+1} = A \\hat x_k + B \\tilde u_k + B_w \\tilde w_k + K \\varepsilon_k$,
    $\\varepsilon_k = y_k - y_0 - C \\hat x_k - D \\tilde u_k$. With K = 0 this is the simulation
    error (output-error focus).
    """
    A, B, C, D, K, Bw = model.A, model.B, model.C, model.D, model.K, model.Bw
    x0 = jnp.zeros(A.shape[0], A.dtype) if x0 is None else x0
    ydev = y - model.y0

    def body(x, inp):
        yk, uk, wk = inp
        e = yk - C @ x - D @ uk
        return A @ x + B @ uk + Bw @ wk + K @ e, e

    _, es = jax.lax.scan(body, x0, (ydev, du, dw))
    return es


__all__ = ["InnovationsSS", "innovations", "pack", "project_stable", "unpack"]
