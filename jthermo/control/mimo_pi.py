"""MIMO PI: full (or neighbour-sparse) N×N gain matrices, the structure a PLC runs.

$$I_k = I_{k-1} + K_i e_k, \\qquad v_k = u_0 + K_p e_k + I_k, \\qquad
u_k = \\mathrm{sat}(v_k + u^{add}_k), \\qquad e_k = r_k - y_k,$$

saturated to [`U_MIN`, `U_MAX`] with back-calculation to the exact limit: the integrator becomes
$I_k + \\mathrm{sat}(v_k) - v_k$ (the feedback's own request, not the feed-forward's), so it holds exactly the value that keeps
the input at its limit (Åström & Hägglund 2006, §3.5), as `DecoupledPI` does in its
decoupled coordinates. A decoupled PI $W_1(K_p e + I)$ is the MIMO PI with $K_p = W_1
\\mathrm{diag}(k_p)$, $K_i = W_1 \\mathrm{diag}(k_p T_s / T_i)$ (`mimo_from`): tuning both
matrices end to end is tuning the PI and its static decoupler jointly. `u_add` is an additive
input after the anti-windup (a schedule feed-forward, `schedule_ff`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._types import Input, Output, Setpoint
from ..errors import ControlError
from ._base import U_MAX, U_MIN, AbstractController
from .decoupled import DecoupledPI
from .pi import DiagonalPI


class MIMOPIState(eqx.Module):
    integ: Float[Array, " nu"]      # integrator, power fraction


class MIMOPI(AbstractController):
    """$u = u_0 + K_p e + I$, $I \\leftarrow I + K_i e$ with full matrices; `mask` (static, 0/1
    per entry, None: full) keeps only the entries allowed (e.g. a zone and its neighbours)."""

    kp: Float[Array, "nu ny"]       # proportional gains, 1/°C, tunable
    ki: Float[Array, "nu ny"]       # integral gains per sample, 1/(°C·sample), tunable
    u0: Float[Array, " nu"]         # input at zero integrator, power fraction
    mask: tuple | None = eqx.field(static=True, default=None)
    ts: float = eqx.field(static=True, default=1.0)
    # the stored kp, ki are in units of these (1: plain gains); `rescaled` sets them to the
    # gains' diagonal magnitude so that an optimiser step of order 1e-2 on a stored entry,
    # diagonal or not, moves the loop by that fraction of the start's gains
    kp_scale: float = eqx.field(static=True, default=1.0)
    ki_scale: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        n = self.u0.shape[0] if self.u0.ndim == 1 else -1
        if self.kp.shape != (n, n) or self.ki.shape != (n, n):
            raise ControlError(f"MIMOPI: kp {self.kp.shape} and ki {self.ki.shape} must be "
                               f"square and match u0 {self.u0.shape}")
        if self.mask is not None and np.shape(self.mask) != (n, n):
            raise ControlError(f"MIMOPI: mask has shape {np.shape(self.mask)}, expected {(n, n)}")

    @property
    def zones(self) -> int:
        return int(self.u0.shape[0])

    def gains(self) -> tuple[Array, Array]:
        """The effective `(Kp, Ki)` (masked, in plain units)."""
        kp, ki = self.kp_scale * self.kp, self.ki_scale * self.ki
        if self.mask is None:
            return kp, ki
        m = jnp.asarray(self.mask, self.kp.dtype)
        return kp * m, ki * m

    def rescaled(self) -> MIMOPI:
        """The same controller with kp, ki stored in units of the mean magnitude of their
        effective diagonals (`kp_scale`, `ki_scale`): what gradient tuning should start from,
        as the off-diagonal entries start at 0 and cannot be tuned in log space."""
        kp, ki = self.kp_scale * self.kp, self.ki_scale * self.ki
        s_p = float(np.mean(np.abs(np.diag(np.asarray(kp))))) or 1.0
        s_i = float(np.mean(np.abs(np.diag(np.asarray(ki))))) or 1.0
        return MIMOPI(kp=kp / s_p, ki=ki / s_i, u0=self.u0, mask=self.mask, ts=self.ts,
                      kp_scale=s_p, ki_scale=s_i)

    def init(self, y0: Output, r0: Setpoint) -> MIMOPIState:
        return MIMOPIState(integ=jnp.zeros_like(self.u0 + 0.0 * y0[:self.zones]))

    def step_offset(self, state: MIMOPIState, y: Output, r: Setpoint,
                    u_add) -> tuple[Input, MIMOPIState]:
        """One sample with an additive input `u_add` inside the saturation and anti-windup."""
        kp, ki = self.gains()
        e = r[:self.zones] - y[:self.zones]
        integ = state.integ + ki @ e
        v = self.u0 + kp @ e + integ
        u = jnp.clip(v + u_add, U_MIN, U_MAX)
        # back-calculation on the feedback's own request: a feed-forward pulse that saturates
        # the heater does not pull the integrator (it would undo the pulse once it ends)
        return u, MIMOPIState(integ + (jnp.clip(v, U_MIN, U_MAX) - v))

    def step(self, state: MIMOPIState, y: Output, r: Setpoint) -> tuple[Input, MIMOPIState]:
        return self.step_offset(state, y, r, 0.0)


def neighbour_mask(zones: int, edges) -> tuple:
    """0/1 mask of a zone and its neighbours (`edges`: pairs of zones, e.g. the printer's
    `grid_edges`), as a static tuple."""
    m = np.eye(zones)
    for i, j in edges:
        m[i, j] = m[j, i] = 1.0
    return tuple(tuple(float(v) for v in row) for row in m)


def mimo_from(ctrl, *, edges=None) -> MIMOPI:
    """The MIMO PI equal to a `DecoupledPI` (exactly, anti-windup included) or a Euler
    `DiagonalPI` (the same linear law; its clamping anti-windup becomes back-calculation);
    with `edges` (pairs of neighbouring zones) only a zone and its neighbours are coupled."""
    if isinstance(ctrl, DecoupledPI):
        W1 = jnp.eye(ctrl.kp.shape[0], dtype=ctrl.kp.dtype) if ctrl.W1 is None else ctrl.W1
        kp, ki, u0 = W1 * ctrl.kp[None, :], W1 * (ctrl.kp * ctrl.ts / ctrl.ti)[None, :], ctrl.u_bias
    elif isinstance(ctrl, DiagonalPI) and ctrl.method == "euler":
        kp, ki, u0 = jnp.diag(ctrl.kp), jnp.diag(ctrl.kp * ctrl.ts / ctrl.ti), ctrl.u0
    else:
        raise ControlError(f"mimo_from: needs a DecoupledPI or an Euler DiagonalPI, got "
                           f"{type(ctrl).__name__}")
    n = int(u0.shape[0])
    return MIMOPI(kp=kp, ki=ki, u0=u0, mask=None if edges is None else neighbour_mask(n, edges),
                  ts=ctrl.ts)
