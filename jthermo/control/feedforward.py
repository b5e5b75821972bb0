"""Feed-forward from the reference (thesis §2.2.4, Fig. 2.2): $u = u_f + F(y_r - y)$.

A reference model $G_m$ turns the set point into the trajectory $y_r$ the plant should follow,
and $F_f = G_m/G$ (eq. 2.15) gives the input $u_f$ that makes the *model* follow it; the
feedback PI $F$ only corrects the mismatch.

- ideal (eq. 2.16): $G_m = \\mathrm{diag}\\,1/(1+sT)$, discretised with a one-sample delay so
  that it has the relative degree of G; $F_f$ is realised as the one-step inverse of the state
  space, $u_f = u_0 + (CB)^{-1}(y_{r,k+1} - y_0 - C A x_m)$, when the model's zeros are stable,
  else (flag `inverse=False`) by the static inverse $G(0)^{-1}$.
- neutral (eq. 2.17): $G_m = G\\,G(0)^{-1}$, so $F_f = G(0)^{-1}$, a constant matrix (as the
  thesis' eq. 4.7).

The model matrices are held fixed (`stop_gradient`); tunable leaves are the PI gains and, for
the ideal design, the reference time constants T.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._types import Input, Output, Setpoint
from ..errors import ControlError
from ._base import AbstractController
from .pi import pi_update
from .rules import as_array, as_state_space, dcgain_inverse, lambda_gains, step_models, zeros_stable

sg = jax.lax.stop_gradient


class FFState(eqx.Module):
    xm: Float[Array, " nx"]      # reference-model state (model deviation coordinates)
    z: Float[Array, " ny"]       # ideal reference trajectory, °C
    integ: Float[Array, " nu"]   # feedback PI integrator


class FeedForward(AbstractController):
    """Reference feed-forward with a diagonal PI on $y_r - y$ and anti-windup on the total input."""

    kp: Float[Array, " nu"]       # feedback PI gain, 1/°C, tunable
    ti: Float[Array, " nu"]       # feedback PI integral time, s, tunable
    T: Float[Array, " ny"]        # ideal reference time constants, s, tunable (unused if neutral)
    A: Float[Array, "nx nx"]      # model (fixed)
    B: Float[Array, "nx nu"]
    C: Float[Array, "ny nx"]
    u_op: Float[Array, " nu"]     # model operating point, power fraction
    y_op: Float[Array, " ny"]     # °C
    G0inv: Float[Array, "nu ny"]  # G(0)^-1
    CBinv: Float[Array, "nu ny"]  # (CB)^-1
    Mss: Float[Array, "nx ny"]    # steady state per unit reference: (I-A)^-1 B G(0)^-1
    kind: str = eqx.field(static=True)        # "ideal" | "neutral"
    inverse: bool = eqx.field(static=True)    # ideal: one-step model inverse (True) or static
    ts: float = eqx.field(static=True)

    def init(self, y0: Output, r0: Setpoint) -> FFState:
        # the reference trajectory starts where the plant is (steady state at y0)
        xm = sg(self.Mss) @ (y0 - sg(self.y_op))
        return FFState(xm=xm, z=y0 + 0.0 * self.T, integ=jnp.zeros_like(self.kp * y0))

    def step(self, state: FFState, y: Output, r: Setpoint) -> tuple[Input, FFState]:
        A, B, C = sg(self.A), sg(self.B), sg(self.C)
        G0inv, CBinv = sg(self.G0inv), sg(self.CBinv)
        y_r = sg(self.y_op) + C @ state.xm
        if self.kind == "neutral":
            uf = self.u_op + G0inv @ (r - sg(self.y_op))
            z_next = state.z
        else:
            a = jnp.exp(-self.ts / self.T)
            z_next = a * state.z + (1.0 - a) * r
            if self.inverse:
                uf = self.u_op + CBinv @ (z_next - sg(self.y_op) - C @ (A @ state.xm))
            else:
                uf = self.u_op + G0inv @ (state.z - sg(self.y_op))
                y_r = state.z
        xm_next = A @ state.xm + B @ (uf - self.u_op)
        u, integ = pi_update(self.kp, self.ti, self.ts, state.integ, y_r - y, uf)
        return u, FFState(xm=xm_next, z=z_next, integ=integ)


def design_feedforward(model, kind: str = "neutral", T=None, lam=None) -> FeedForward:
    """Reference feed-forward from a model (thesis eq. 2.15–2.17).

    **Arguments:**
    - `kind`: `"neutral"` ($G_m = G G(0)^{-1}$) or `"ideal"` ($G_m = 1/(1+sT)$).
    - `T`: ideal reference time constant in s, scalar or per output (default: half of each
      channel's open-loop time constant).
    - `lam`: lambda of the feedback PI (default: the open-loop T, as `design_lambda_pi`).
    """
    if kind not in ("ideal", "neutral"):
        raise ControlError(f"design_feedforward: kind must be 'ideal' or 'neutral', got {kind!r}")
    ss = as_state_space(model)
    sm = step_models(model)
    kp, ti = lambda_gains(sm, lam)
    A, B, C = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C))
    G0inv = dcgain_inverse(ss, "design_feedforward")
    CB = C @ B
    CBinv = np.linalg.pinv(CB)
    Mss = np.linalg.solve(np.eye(A.shape[0]) - A, B @ G0inv)
    Tref = 0.5 * sm.T if T is None else np.broadcast_to(np.asarray(T, np.float64), sm.T.shape)
    if np.any(Tref <= 0):
        raise ControlError(f"design_feedforward: T must be positive, got {T}")
    inverse = kind == "ideal" and zeros_stable(model)
    f = as_array
    return FeedForward(kp=f(kp), ti=f(ti), T=f(Tref), A=f(A), B=f(B), C=f(C), u_op=f(ss.u0),
                       y_op=f(ss.y0), G0inv=f(G0inv), CBinv=f(CBinv), Mss=f(Mss), kind=kind,
                       inverse=bool(inverse), ts=ss.ts)
