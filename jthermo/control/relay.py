"""`pid_relay`: the relay auto-tune 3D-printer firmware runs (Klipper's `PID_CALIBRATE`,
Marlin's `M303`), run on the design model instead of the heater, then Ziegler–Nichols PID.

**Relay test** (Åström & Hägglund 1984; 2006, §2.7). Around the set point's equilibrium input
$u^*$ the input is switched between $u^* + d_1$ (heating) and $u^* - d_2$ (cooling): heating
until $y > r + \\varepsilon$, cooling until $y < r - \\varepsilon$ (hysteresis
$\\varepsilon$). By default the relay is symmetric about $u^*$, $d_1 = d_2 = d$ as large as the
input limits allow: Marlin's `M303` adapts its bias until the on and off times are equal,
which on the design model is $u^*$ itself. `amplitude="full"` switches full power on and off
as Klipper's `PID_CALIBRATE` does, $d_1 = u_{max} - u^*$, $d_2 = u^* - u_{min}$: an
*asymmetric* relay whenever $u^*$ is not mid-range. The loop settles into a limit cycle of
period $P_u$, output amplitude $a$, heating for a fraction $\\delta = t_{on}/P_u$ of each
period. The firmware takes $a$ as half the peak-to-peak swing (`measure="peaks"`); by default
$a$ is the amplitude of the output's first harmonic (`measure="harmonic"`), the quantity the
describing function actually relates to the relay's first harmonic: a lag-dominated heater
gives a near-triangular output whose peaks overstate that harmonic (by $\\pi^2/8$ for a
triangle), so the peak rule underestimates $K_u$ there.

**Ultimate gain with the asymmetric-relay correction.** The describing-function argument
keeps only the first harmonic of the relay output. For a symmetric relay ($d_1 = d_2 = d$,
$\\delta = 1/2$) that harmonic has amplitude $4d/\\pi$, hence $K_u = 4d/(\\pi a)$. For levels
$+d_1$ during $\\delta P_u$ and $-d_2$ for the rest, the Fourier coefficients of the square wave
(time origin at the middle of the heating pulse) give the first-harmonic amplitude

$$U_1 = \\frac{2 (d_1 + d_2)}{\\pi} \\sin(\\pi \\delta),$$

the DC part $d_1\\delta - d_2(1-\\delta)$ moving only the mean, not the oscillation. So

$$K_u = \\frac{2 (d_1 + d_2) \\sin(\\pi\\delta)}{\\pi \\sqrt{a^2 - \\varepsilon^2}},$$

which is $4d/(\\pi a)$ for the symmetric relay without hysteresis; $\\sqrt{a^2-\\varepsilon^2}$
is the magnitude of the relay's $-1/N(a)$ point with hysteresis. This is the correction for
unequal on/off times that asymmetric relay tuning is about (Taysom & Sorensen 2019, the
reference given for Klipper's calibration); the formula here is derived from the square wave.
An asymmetric relay also oscillates away from the phase crossover (its switching instants are
not those of the first harmonic), so its $P_u$ is biased: the symmetric relay is the default.

**Ziegler–Nichols** (1942): $K_p = 0.6 K_u$, $T_i = P_u/2$, $T_d = P_u/8$, run as `DiagonalPID`:
derivative on the measurement through a first-order filter $T_f = T_d/N$, integral frozen
while the output is saturated and the error would push it further (conditional integration,
Åström & Hägglund 2006, §3.5, §13.3), backward-Euler discretisation. Its proportional part
can carry a set-point weight $b \\in [0, 1]$ (two degrees of freedom, `pi.p_error`; default
$b = 1$, the firmware's law).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._types import Input, Output, Setpoint
from ..errors import ControlError
from ._base import U_MAX, U_MIN
from .pi import SetpointWeighted, weight_angle
from .rules import as_array, as_state_space

#: derivative filter: $T_f = T_d / N$
FILTER_N = 10.0


class PIDState(eqx.Module):
    integral: Float[Array, " zones"]     # power fraction
    deriv: Float[Array, " zones"]        # filtered derivative term, power fraction
    y_prev: Float[Array, " zones"]       # previous measurement, °C
    y_ref: Float[Array, " zones"]        # measurement at the start, °C (set-point weight)


class DiagonalPID(SetpointWeighted):
    """One PID per zone, $u = u_0 + K_p e_b + I + D$ with $e = r - y$ and
    $e_b = e - (1 - b)(r - y_0)$ (set-point weight $b = \\sin^2\\theta$, $y_0$ the measurement
    at `init`; $b = 1$, the default, gives $e_b = e$):
    $I_k = I_{k-1} + K_p T_s/T_i\\, e_k$ (frozen while saturated further),
    $D_k = \\frac{T_f}{T_f + T_s} D_{k-1} - \\frac{K_p T_d}{T_f + T_s}(y_k - y_{k-1})$,
    $T_f = T_d/N$ (derivative on the measurement: a set-point step gives no kick).
    `kp` (1/°C), `ti`, `td` (s), `u0` and `b_angle` ($\\theta$; constructor argument `b`;
    None, the default: no weight, $b = 1$) are array leaves (tunable); the rest is static."""

    kp: Float[Array, " zones"]
    ti: Float[Array, " zones"]
    td: Float[Array, " zones"]
    u0: Float[Array, " zones"]
    b_angle: Float[Array, " zones"] | None = None   # None: b = 1, not a tuned leaf
    ts: float = eqx.field(static=True, default=1.0)
    n_filter: float = eqx.field(static=True, default=FILTER_N)
    u_min: float = eqx.field(static=True, default=U_MIN)
    u_max: float = eqx.field(static=True, default=U_MAX)

    def __init__(self, kp, ti, td, u0=0.5, *, ts: float = 1.0, n_filter: float = FILTER_N,
                 u_min: float = U_MIN, u_max: float = U_MAX, b=None):
        kp, ti, td = (jnp.atleast_1d(jnp.asarray(g)) for g in (kp, ti, td))
        if not (kp.ndim == ti.ndim == td.ndim == 1 and kp.shape == ti.shape == td.shape):
            raise ControlError(f"DiagonalPID: kp, ti and td must be 1-D of one length, got "
                               f"{kp.shape}, {ti.shape} and {td.shape}")
        dtype = jnp.result_type(kp.dtype, ti.dtype, td.dtype, float)
        self.kp, self.ti, self.td = (g.astype(dtype) for g in (kp, ti, td))
        self.u0 = jnp.broadcast_to(jnp.asarray(u0, dtype), kp.shape)
        self.b_angle = None if b is None else weight_angle(b, self.kp)
        self.ts, self.n_filter = float(ts), float(n_filter)
        self.u_min, self.u_max = float(u_min), float(u_max)

    def __check_init__(self):
        if not (self.ts > 0 and self.n_filter > 0 and self.u_min < self.u_max):
            raise ControlError("DiagonalPID: needs ts > 0, n_filter > 0 and u_min < u_max")

    @property
    def zones(self) -> int:
        return int(self.kp.shape[0])

    def init(self, y0: Output, r0: Setpoint) -> PIDState:
        z = jnp.zeros_like(self.kp)
        y0 = jnp.asarray(y0, self.kp.dtype)[:self.zones] + z
        return PIDState(integral=z, deriv=z, y_prev=y0, y_ref=y0)

    def step(self, state: PIDState, y: Output, r: Setpoint) -> tuple[Input, PIDState]:
        y = jnp.asarray(y)[:self.zones]
        r = jnp.asarray(r)[:self.zones]
        e = r - y
        inc = self.kp * (self.ts / self.ti) * e
        tf = self.td / self.n_filter
        deriv = (tf * state.deriv - self.kp * self.td * (y - state.y_prev)) / (tf + self.ts)
        i_try = state.integral + inc
        v = self.u0 + self.kp * self.p_term(e, r, state) + i_try + deriv
        u = jnp.clip(v, self.u_min, self.u_max)
        wind = ((v > self.u_max) & (inc > 0)) | ((v < self.u_min) & (inc < 0))
        integral = jnp.where(wind, state.integral, i_try)
        return u, PIDState(integral=integral, deriv=deriv, y_prev=y, y_ref=state.y_ref)


class RelayResult(NamedTuple):
    """One loop's relay test: ultimate gain `ku` (power fraction per °C) and period `pu` (s),
    the oscillation's half peak-to-peak amplitude `a` (°C), the heating fraction `duty`, the
    relay levels `d_on`, `d_off` above / below the equilibrium input, and the recorded
    trajectories `y` (°C) and `u` of the test."""

    ku: float
    pu: float
    a: float
    duty: float
    d_on: float
    d_off: float
    y: np.ndarray
    u: np.ndarray


def relay_test(model, loop: int = 0, *, amplitude=None, hysteresis: float = 0.0,
               measure: str = "harmonic",
               u_min: float = U_MIN, u_max: float = U_MAX, cycles: int = 4,
               max_steps: int | None = None) -> RelayResult:
    """Relay feedback on output/input `loop` of `model` (a design-point model: its `u0`, `y0`
    are the equilibrium input and the set point), the other inputs held at their equilibrium.

    `amplitude`: relay step either side of $u^*$ (power fraction), clipped to the limits;
    None (default): the largest symmetric step within [`u_min`, `u_max`] (Marlin); `"full"`:
    full power on and off (Klipper), asymmetric. `measure`: `"harmonic"` (default, the
    output's first-harmonic amplitude) or `"peaks"` (half the peak-to-peak swing, as the
    firmware does).
    `hysteresis` (°C): switching band $\\pm\\varepsilon$ around the set point. The test runs
    until `cycles` full periods follow two settling periods; `ControlError` when the model does
    not oscillate (no switch) within `max_steps` samples."""
    ss = as_state_space(model)
    A, B, C, D = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    u_star = float(np.asarray(ss.u0, np.float64)[loop])
    r = float(np.asarray(ss.y0, np.float64)[loop])
    if measure not in ("harmonic", "peaks"):
        raise ControlError(f"pid_relay: measure must be harmonic or peaks, got {measure!r}")
    d_on, d_off = u_max - u_star, u_star - u_min
    if amplitude is None:
        d_on = d_off = min(d_on, d_off)
    elif amplitude != "full":
        d_on, d_off = min(d_on, float(amplitude)), min(d_off, float(amplitude))
    if not (d_on > 0 and d_off > 0):
        raise ControlError(f"pid_relay: the equilibrium input {u_star:.3g} of loop {loop} leaves "
                           f"no room for a relay within [{u_min:g}, {u_max:g}]")
    eps = float(hysteresis)
    if max_steps is None:
        rho = float(np.max(np.abs(np.linalg.eigvals(A))))
        tau = 1.0 if rho < 1e-12 else -1.0 / math.log(rho)
        max_steps = int(min(400 * tau + 2000, 2_000_000))
    x = np.zeros(A.shape[0])
    b, c, dd = B[:, loop], C[loop], D[loop, loop]
    heating, du = True, d_on
    ys, us, ons = [], [], []
    for k in range(max_steps):
        y = r + c @ x + dd * du
        if heating and y > r + eps:
            heating = False
        elif not heating and y < r - eps:
            heating = True
            ons.append(k)
        du = d_on if heating else -d_off
        ys.append(y)
        us.append(u_star + du)
        x = A @ x + b * du
        if len(ons) >= cycles + 3:
            break
    if len(ons) < cycles + 3:
        raise ControlError(f"pid_relay: the relay test on loop {loop} did not oscillate within "
                           f"{max_steps} samples ({max_steps * ss.ts:g} s)")
    start, stop = ons[-cycles - 1], ons[-1]
    y_c, u_c = np.array(ys[start:stop]), np.array(us[start:stop])
    pu = (stop - start) * ss.ts / cycles
    if measure == "peaks":
        a = 0.5 * (float(y_c.max()) - float(y_c.min()))
    else:
        phase = np.exp(-2j * np.pi * cycles * np.arange(y_c.size) / y_c.size)
        a = 2.0 * abs(complex(np.mean(y_c * phase)))
    duty = float(np.mean(u_c > u_star))
    if a <= eps:
        raise ControlError(f"pid_relay: the oscillation ({a:.3g} °C) is inside the hysteresis")
    u1 = 2.0 * (d_on + d_off) * math.sin(math.pi * duty) / math.pi
    ku = u1 / math.sqrt(a * a - eps * eps)
    return RelayResult(ku, pu, a, duty, d_on, d_off, np.array(ys), np.array(us))


def ziegler_nichols(ku: float, pu: float) -> tuple[float, float, float]:
    """Ziegler–Nichols PID from the ultimate gain and period: `(kp, ti, td)` =
    `(0.6 ku, pu / 2, pu / 8)`."""
    return 0.6 * ku, 0.5 * pu, 0.125 * pu


def design_pid_relay(model, *, amplitude=None, hysteresis: float = 0.0,
                     measure: str = "harmonic", u_min: float = U_MIN, u_max: float = U_MAX) -> DiagonalPID:
    """The firmware's auto-tune on the model: one relay test per loop (`relay_test`, the other
    heaters at their equilibrium), Ziegler–Nichols gains, a `DiagonalPID` biased at the
    model's operating-point input (the set point's equilibrium when called from `design`)."""
    ss = as_state_space(model)
    gains = [ziegler_nichols(t.ku, t.pu) for t in
             (relay_test(model, i, amplitude=amplitude, hysteresis=hysteresis, measure=measure,
                         u_min=u_min, u_max=u_max) for i in range(ss.B.shape[1]))]
    kp, ti, td = (np.array(g) for g in zip(*gains))
    return DiagonalPID(as_array(kp), as_array(ti), as_array(td),
                       as_array(np.asarray(ss.u0, np.float64)), ts=ss.ts, u_min=u_min,
                       u_max=u_max)


__all__ = ["DiagonalPID", "PIDState", "RelayResult", "design_pid_relay", "relay_test",
           "ziegler_nichols"]
