"""PI control with a static decoupler: $F(z) = W_1 F_{diag}(z)$ (thesis eq. 2.12–2.14).

With $W_1 = I$ this is the diagonal PI. The PI law is discretised with Euler backward
(thesis eq. 2.8): $I_k = I_{k-1} + K_p T_s/T_i\\, e_k$, $v_k = K_p e_k + I_k$,
$u_k = u_b + W_1 v_k$. Anti-windup by back-calculation in the decoupled coordinates: after
saturation, $I_k \\leftarrow I_k + W_1^{-1}(\\mathrm{sat}(u_k) - u_k)$, so the integrators hold
exactly the value that keeps the input at its limit (Åström & Hägglund 2006, §3.5); one
sample is `pi.pi_update`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._types import Input, Output, Setpoint
from ..errors import ControlError
from ._base import AbstractController
from .pi import UNTUNED_KP, UNTUNED_TI, DiagonalPI, pi_update
from .rules import (
    as_array,
    as_state_space,
    bias_input,
    decoupling_matrix,
    lambda_gains,
    step_models,
)


class DecoupledPIState(eqx.Module):
    integ: Float[Array, " nu"]      # integrator, in decoupled input units


class DecoupledPI(AbstractController):
    """$u = u_b + W_1 (K_p e + I)$ with $e = r - y$, Euler-backward PI and anti-windup.

    `W1 = None` (static) gives the diagonal PI.
    """

    kp: Float[Array, " nu"]          # proportional gain, 1/°C (decoupled units), tunable
    ti: Float[Array, " nu"]          # integral time, s, tunable
    u_bias: Float[Array, " nu"]      # input at zero integrator, power fraction
    W1: Float[Array, "nu ny"] | None  # static decoupler, tunable when present
    ts: float = eqx.field(static=True)

    def __init__(self, kp, ti, u_bias=0.5, W1=None, *, ts: float = 1.0):
        self.kp = jnp.asarray(kp)
        self.ti = jnp.asarray(ti)
        self.u_bias = jnp.broadcast_to(jnp.asarray(u_bias, self.kp.dtype), self.kp.shape)
        self.W1 = None if W1 is None else jnp.asarray(W1)
        self.ts = float(ts)

    def __check_init__(self):
        n = self.kp.shape
        if self.kp.ndim != 1 or self.ti.shape != n:
            raise ControlError(f"DecoupledPI: kp {self.kp.shape} and ti {self.ti.shape} must be "
                               "equal 1-D shapes")
        if self.W1 is not None and self.W1.shape != (n[0], n[0]):
            raise ControlError(f"DecoupledPI: W1 has shape {self.W1.shape}, expected {(n[0], n[0])}")

    def init(self, y0: Output, r0: Setpoint) -> DecoupledPIState:
        return DecoupledPIState(integ=jnp.zeros_like(self.kp * jnp.asarray(y0)))

    def step(self, state: DecoupledPIState, y: Output, r: Setpoint) -> tuple[Input, DecoupledPIState]:
        e = r - y
        u, integ = pi_update(self.kp, self.ti, self.ts, state.integ, e, self.u_bias, self.W1)
        return u, DecoupledPIState(integ)


def design_lambda_pi(model, lam=None, *, u_bias=None) -> DiagonalPI:
    """Diagonal PI (`DiagonalPI`, clamping anti-windup), lambda-tuned per channel on the
    three-parameter step model (eq. 2.10).

    `lam`: closed-loop time constant in s (default: each channel's open-loop T).
    `u_bias`: input at zero integrator (default: the model's operating-point input).
    """
    ss = as_state_space(model)
    kp, ti = lambda_gains(step_models(model), lam)
    ub = bias_input(model, u_bias)
    return DiagonalPI(as_array(kp), as_array(ti), as_array(ub), ts=ss.ts)


def design_decoupled_pi(model, kind: str = "CB", lam=None, *, u_bias=None) -> DecoupledPI:
    """Decoupled PI $W_1 F_{diag}$: $W_1 = (CB)^{-1}$ (`kind="CB"`, eq. 2.14) or $G(0)^{-1}$
    (`kind="G0"`, eq. 2.13); $F_{diag}$ is lambda-tuned on the diagonal of $G W_1$."""
    ss = as_state_space(model)
    W1 = decoupling_matrix(model, kind)
    kp, ti = lambda_gains(step_models(model, transform=W1), lam)
    ub = bias_input(model, u_bias)
    return DecoupledPI(as_array(kp), as_array(ti), as_array(ub), as_array(W1), ts=ss.ts)


def design_untuned_pi(model, *, kp: float = UNTUNED_KP, ti: float = UNTUNED_TI,
                      u_bias=None) -> DiagonalPI:
    """The untuned baseline: the same PI on every zone whatever the model says
    (`DiagonalPI.untuned` gains), biased at the model's operating-point input."""
    ss = as_state_space(model)
    n = ss.B.shape[1]
    ub = bias_input(model, u_bias)
    return DiagonalPI(jnp.full(n, kp), jnp.full(n, ti), as_array(ub), ts=ss.ts)
