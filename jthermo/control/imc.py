"""Internal model control (thesis §2.2.5, Fig. 2.3, eq. 2.18).

The internal model $G$ runs beside the plant on the *saturated* input; only the mismatch
$\\hat d = y - \\hat y_m$ is fed back. With $Q = F_\\lambda G^{-1}$ and the filter
$F_\\lambda = \\mathrm{diag}\\,(1-a)z^{-1}/(1 - a z^{-1})$, $a = e^{-T_s/\\lambda}$, the filter
has the model's relative degree (one), so $Q$ is realisable: each sample,

$$z_{k+1} = a z_k + (1-a)(r_k - \\hat d_k), \\qquad
  u_k = u_0 + (CB)^{-1}\\bigl(z_{k+1} - y_0 - C A \\hat x_k\\bigr),$$

which puts the model output on the filtered target one sample later (Morari & Zafiriou 1989,
ch. 4; Glad & Ljung 2006). When the model has zeros outside the unit circle the inverse is
unstable and $G^{-1}$ is replaced by the static $G(0)^{-1}$ (`inverse=False`). Because the
model is driven by the saturated input, IMC needs no separate anti-windup. With a perfect
model the closed loop is $y = G Q r = F_\\lambda r$ (eq. 2.18).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._types import Input, Output, Setpoint
from ..errors import ControlError
from ._base import U_MAX, U_MIN, AbstractController
from .rules import as_array, as_state_space, dcgain_inverse, step_models, zeros_stable

sg = jax.lax.stop_gradient


class IMCState(eqx.Module):
    xm: Float[Array, " nx"]    # internal-model state (deviation coordinates)
    z: Float[Array, " ny"]     # filtered target for the model output, °C


class IMC(AbstractController):
    """IMC with a first-order filter per output; tunable leaves: the filter time constants."""

    lam: Float[Array, " ny"]      # filter time constants, s, tunable
    A: Float[Array, "nx nx"]      # internal model (fixed)
    B: Float[Array, "nx nu"]
    C: Float[Array, "ny nx"]
    u_op: Float[Array, " nu"]
    y_op: Float[Array, " ny"]
    CBinv: Float[Array, "nu ny"]
    G0inv: Float[Array, "nu ny"]
    Mss: Float[Array, "nx ny"]    # (I-A)^-1 B G(0)^-1
    inverse: bool = eqx.field(static=True)
    ts: float = eqx.field(static=True)

    def init(self, y0: Output, r0: Setpoint) -> IMCState:
        xm = sg(self.Mss) @ (y0 - sg(self.y_op))
        return IMCState(xm=xm, z=y0 + 0.0 * self.lam)

    def step(self, state: IMCState, y: Output, r: Setpoint) -> tuple[Input, IMCState]:
        A, B, C = sg(self.A), sg(self.B), sg(self.C)
        d_hat = y - (sg(self.y_op) + C @ state.xm)
        a = jnp.exp(-self.ts / self.lam)
        z_next = a * state.z + (1.0 - a) * (r - d_hat)
        if self.inverse:
            u = self.u_op + sg(self.CBinv) @ (z_next - sg(self.y_op) - C @ (A @ state.xm))
        else:
            u = self.u_op + sg(self.G0inv) @ (z_next - sg(self.y_op))
        u = jnp.clip(u, U_MIN, U_MAX)
        xm_next = A @ state.xm + B @ (u - self.u_op)
        return u, IMCState(xm=xm_next, z=z_next)


def design_imc(model, filter_tc=None) -> IMC:
    """IMC from a model. `filter_tc`: filter time constant λ in s, scalar or per output
    (default: a third of each channel's open-loop time constant)."""
    ss = as_state_space(model)
    A, B, C = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C))
    G0inv = dcgain_inverse(ss, "design_imc")
    inverse = zeros_stable(model)
    CBinv = np.linalg.pinv(C @ B)
    if filter_tc is None:
        lam = step_models(model).T / 3.0
    else:
        lam = np.broadcast_to(np.asarray(filter_tc, np.float64), (C.shape[0],)).copy()
    if np.any(~np.isfinite(lam)) or np.any(lam <= 0):
        raise ControlError(f"design_imc: filter_tc must be positive, got {filter_tc}")
    Mss = np.linalg.solve(np.eye(A.shape[0]) - A, B @ G0inv)
    f = as_array
    return IMC(lam=f(lam), A=f(A), B=f(B), C=f(C), u_op=f(ss.u0), y_op=f(ss.y0),
               CBinv=f(CBinv), G0inv=f(G0inv), Mss=f(Mss), inverse=bool(inverse), ts=ss.ts)
