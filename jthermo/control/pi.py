"""Diagonal (decentralised) PI control: one PI loop per zone, with anti-windup.

Discretised with backward Euler (Åström & Hägglund 2006, §3.5, §13.3):

$$u_k = u_0 + K_p e_k + I_k, \\qquad I_k = I_{k-1} + \\frac{K_p T_s}{T_i} e_k ,$$

(or Tustin: $I_k = I_{k-1} + \\frac{K_p T_s}{2 T_i}(e_k + e_{k-1})$), saturated to
[`u_min`, `u_max`]. Anti-windup by clamping (conditional integration: the integral is frozen
while the output is saturated and the error would drive it further) or by back-calculation
(the integral is pulled back by $\\frac{T_s}{T_t}(\\mathrm{sat}(v) - v)$).

Set-point weight (two degrees of freedom, Åström & Hägglund 2006, §3.4): the proportional
part acts on $b\\,\\tilde r - \\tilde y$ in deviations from the measurement $y_0$ the loop
starts from, $K_p\\big(e_k - (1 - b)(r_k - y_0)\\big)$, the integral on $e = r - y$; so a
set-point step of size $\\Delta$ kicks the input by $b K_p \\Delta$ and the integral brings
the rest. $b = \\sin^2\\theta \\in [0, 1]$ (the leaf is $\\theta$, smooth and unconstrained);
Without `b` there is no weight leaf and the law is the one-degree-of-freedom PI bit for bit
(`with_setpoint_weight` adds one; $b = 1$ is a stationary point of $\\sin^2\\theta$, so a
weight that should be tuned starts below 1).

`pi_update` is the Euler-backward sample with back-calculation to the exact limit, behind a
static matrix $W_1$ (the decoupled PI and the feed-forward's feedback PI).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..errors import ControlError
from ._base import U_MAX, U_MIN, AbstractController

#: the original solution's PI: the same gains on every zone (thesis §1.1), untuned for the bed
UNTUNED_KP = 0.15     # power fraction per °C
UNTUNED_TI = 30.0     # s


def pi_update(kp, ti, ts, integ, e, u_open, W1=None):
    """One Euler-backward PI sample with back-calculation anti-windup, $u = u_{open} + W_1 v$.

    `u_open` is everything added to $W_1 v$ (bias, feed-forward); after saturation to
    [`U_MIN`, `U_MAX`] the integrator is moved by $W_1^{-1}(\\mathrm{sat}(u) - u)$.
    Returns `(u_sat, integ_new)`.
    """
    integ_try = integ + kp * (ts / ti) * e
    v = kp * e + integ_try
    u_req = u_open + (v if W1 is None else W1 @ v)
    u_sat = jnp.clip(u_req, U_MIN, U_MAX)
    du = u_sat - u_req
    integ_new = integ_try + (du if W1 is None else jnp.linalg.solve(W1, du))
    return u_sat, integ_new


def weight_angle(b, like) -> Array:
    """$\\theta = \\arcsin\\sqrt{b}$, the leaf of a set-point weight $b = \\sin^2\\theta$,
    broadcast to `like`'s shape and dtype; `ControlError` unless $0 \\le b \\le 1$."""
    try:
        bad = not 0.0 <= float(jnp.min(jnp.asarray(b))) <= float(jnp.max(jnp.asarray(b))) <= 1.0
    except (TypeError, ValueError):
        bad = True
    if bad:
        raise ControlError(f"set-point weight b must lie in [0, 1], got {b!r}")
    return jnp.broadcast_to(jnp.arcsin(jnp.sqrt(jnp.asarray(b, like.dtype))), like.shape)


def with_setpoint_weight(controller, b):
    """`controller` (a PI or PID with a set-point weight) with weight `b` as a tunable leaf."""
    return eqx.tree_at(lambda c: c.b_angle, controller, weight_angle(b, controller.kp),
                       is_leaf=lambda x: x is None)


def p_error(e, b, r, y_ref):
    """The proportional part's error with set-point weight $b$: $e - (1 - b)(r - y_{ref})$
    (exactly $e$ when $b = 1$)."""
    return e - (1.0 - b) * (r - y_ref)


class PIState(eqx.Module):
    integral: Float[Array, " zones"]    # power fraction
    error: Float[Array, " zones"]       # previous error (Tustin), °C
    y_ref: Float[Array, " zones"]       # measurement at the start, °C (set-point weight)


class SetpointWeighted(AbstractController):
    """A PI-type loop per zone with an optional set-point weight: subclasses have the leaves
    `kp` and `b_angle` (None: no weight) and a state with `y_ref`."""

    @property
    def b(self) -> Array:
        """The set-point weight $b = \\sin^2\\theta$."""
        if self.b_angle is None:
            return jnp.ones_like(self.kp)
        return jnp.sin(self.b_angle) ** 2

    def p_term(self, e, r, state):
        """The proportional part's error: $e$, or $e - (1 - b)(r - y_{ref})$ with a weight."""
        return e if self.b_angle is None else p_error(e, self.b, r, state.y_ref)


class DiagonalPI(SetpointWeighted):
    """One PI loop per zone: `kp` (1/°C), `ti` (s), the bias `u0` (power fraction) and the
    set-point weight's angle `b_angle` ($b = \\sin^2\\theta$, property `b`; constructor
    argument `b`; None, the default, is no weight: $b = 1$, no leaf) are array leaves, so
    `jax.grad` reaches them; `ts`, the limits and the discretisation are static.
    """

    kp: Float[Array, " zones"]
    ti: Float[Array, " zones"]
    u0: Float[Array, " zones"]
    b_angle: Float[Array, " zones"] | None = None   # None: b = 1, not a tuned leaf
    ts: float = eqx.field(static=True, default=1.0)
    u_min: float = eqx.field(static=True, default=U_MIN)
    u_max: float = eqx.field(static=True, default=U_MAX)
    antiwindup: str = eqx.field(static=True, default="clamp")   # "clamp" | "backcalc" | "none"
    method: str = eqx.field(static=True, default="euler")       # "euler" (backward) | "tustin"
    tt: float | None = eqx.field(static=True, default=None)     # s, back-calculation time

    def __init__(self, kp, ti, u0=0.5, *, ts: float = 1.0, u_min: float = U_MIN,
                 u_max: float = U_MAX, antiwindup: str = "clamp", method: str = "euler",
                 tt: float | None = None, b=None):
        kp = jnp.asarray(kp)
        ti = jnp.asarray(ti)
        if kp.ndim == 0:
            kp = kp[None]
        ti = ti.reshape(-1)
        if kp.ndim != 1 or (kp.shape[0] != ti.shape[0] and 1 not in (kp.shape[0], ti.shape[0])):
            raise ControlError(f"DiagonalPI: kp and ti must be 1-D of one length, got "
                               f"{kp.shape} and {ti.shape}")
        n = max(kp.shape[0], ti.shape[0])
        dtype = jnp.result_type(kp.dtype, ti.dtype, float)
        self.kp = jnp.broadcast_to(kp, (n,)).astype(dtype)
        self.ti = jnp.broadcast_to(ti, (n,)).astype(dtype)
        self.u0 = jnp.broadcast_to(jnp.asarray(u0, dtype), (n,))
        self.b_angle = None if b is None else weight_angle(b, self.kp)
        self.ts = float(ts)
        self.u_min, self.u_max = float(u_min), float(u_max)
        self.antiwindup = antiwindup
        self.method = method
        self.tt = None if tt is None else float(tt)

    def __check_init__(self):
        if self.antiwindup not in ("clamp", "backcalc", "none"):
            raise ControlError(f"DiagonalPI: antiwindup must be clamp, backcalc or none, got {self.antiwindup!r}")
        if self.method not in ("euler", "tustin"):
            raise ControlError(f"DiagonalPI: method must be euler or tustin, got {self.method!r}")
        if not self.u_min < self.u_max:
            raise ControlError("DiagonalPI: u_min must be below u_max")
        if self.kp.ndim != 1 or self.ti.shape != self.kp.shape:
            raise ControlError(f"DiagonalPI: kp and ti must be 1-D of one length, got "
                               f"{self.kp.shape} and {self.ti.shape}")
        if not (isinstance(self.ts, float) and self.ts > 0):
            raise ControlError(f"DiagonalPI: ts must be > 0, got {self.ts}")

    @classmethod
    def untuned(cls, zones: int, *, ts: float = 1.0, kp: float = UNTUNED_KP,
                ti: float = UNTUNED_TI, u0: float = 0.5) -> DiagonalPI:
        """The original solution: the same PI on every zone, tuned for no model in particular."""
        if not (isinstance(zones, int) and zones >= 1):
            raise ControlError(f"DiagonalPI.untuned: zones must be a positive integer, got {zones!r}")
        return cls(jnp.full((zones,), kp), jnp.full((zones,), ti), u0, ts=ts)

    @property
    def zones(self) -> int:
        return int(self.kp.shape[0])

    def init(self, y0, r0=None) -> PIState:
        z = jnp.zeros_like(self.kp)
        e0 = z if r0 is None else jnp.asarray(r0, self.kp.dtype)[:self.zones] - jnp.asarray(y0)[:self.zones]
        return PIState(integral=z, error=e0, y_ref=jnp.asarray(y0, self.kp.dtype)[:self.zones] + z)

    def step(self, state: PIState, y, r) -> tuple[Array, PIState]:
        r = jnp.asarray(r)[:self.zones]
        e = r - jnp.asarray(y)[:self.zones]
        ki = self.kp * self.ts / self.ti
        if self.method == "tustin":
            inc = 0.5 * ki * (e + state.error)
        else:
            inc = ki * e
        i_try = state.integral + inc
        v = self.u0 + self.kp * self.p_term(e, r, state) + i_try
        u = jnp.clip(v, self.u_min, self.u_max)
        if self.antiwindup == "clamp":
            wind = ((v > self.u_max) & (inc > 0)) | ((v < self.u_min) & (inc < 0))
            integral = jnp.where(wind, state.integral, i_try)
        elif self.antiwindup == "backcalc":
            tt = self.tt if self.tt is not None else None
            tt = jnp.sqrt(self.ti * self.ts) if tt is None else tt
            integral = i_try + (self.ts / tt) * (u - v)
        else:
            integral = i_try
        return u, PIState(integral=integral, error=e, y_ref=state.y_ref)
