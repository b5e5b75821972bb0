"""The PID law Klipper runs (`klippy/extras/heaters.py`, `ControlPID` and `Heater.set_pwm`) as a
jthermo controller, and the relay auto-tune its `PID_CALIBRATE` runs
(`klippy/extras/pid_calibrate.py`), run on a model.

**Klipper's law**, per heater, at each temperature update (period $\\Delta t$; here the loop's
sample time), with the config's gains $K_p, K_i, K_d$ divided by `PID_PARAM_BASE` = 255 (the
config gains are in duty/255 per °C, per °C·s and per °C/s):

- derivative of the *measurement*, smoothed over `smooth_time` $\\tau$ (default 1 s):
  $\\dot T_k = (T_k - T_{k-1})/\\Delta t$ when $\\Delta t \\ge \\tau$, else
  $\\dot T_k = (\\dot T_{k-1}(\\tau - \\Delta t) + T_k - T_{k-1})/\\tau$;
- integral of the error $e = r - T$ in °C·s, clamped to $[0, P_{max}/K_i]$:
  $I' = \\mathrm{clip}(I_{k-1} + e_k \\Delta t, 0, P_{max}/K_i)$;
- $c = K_p e_k + K_i I' - K_d \\dot T_k$, the duty $\\mathrm{clip}(c, 0, P_{max})$ with
  $P_{max}$ = `max_power`, and $I_k = I'$ only when $c$ was not clipped (else $I_{k-1}$);
- the duty is 0 while the target is not above 0, and a change smaller than
  `MIN_PWM_CHANGE_RATIO` $\\cdot P_{max}$ is not sent unless `HOLD_S` passed since the last one
  was (or, from a duty of 0, never): `Heater.set_pwm`'s update suppression (`pwm_hold`).

The loop starts settled (`init`): $T_{-1} = T_0$, $\\dot T = 0$, and, when the first
measurement is within `SETTLED_C` of the set point, the integral that holds the design's input
`u_hold` ($I = u P_{base}/K_i$) and that duty as the last one sent; from further away (a cold
start) the integral and the duty start at 0, as on a printer whose heater was off.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..control._base import AbstractController
from ..control.rules import as_state_space
from ..errors import ControlError

#: Klipper's gain scale: config gains are per 255 of full duty
PID_PARAM_BASE = 255.0
#: Klipper's default derivative smoothing time, s
SMOOTH_TIME = 1.0
#: `Heater.set_pwm`: changes below this share of max_power are suppressed ...
MIN_PWM_CHANGE_RATIO = 0.05
#: ... unless this long passed since the reading whose duty was last sent: the send time (the
#: reading plus one sensor report period, 0.3 s for an ADC thermistor's REPORT_TIME) plus
#: MAX_HEAT_TIME (3 s) less three report periods and 1 ms
HOLD_S = 0.3 + 3.0 - 3 * 0.3 - 0.001
#: the loop starts with the integral holding `u_hold` when it starts this close to its target
SETTLED_C = 1.0
#: `pid_calibrate.py`: the relay switches off at the target and on again this far below it
TUNE_PID_DELTA = 5.0


class KlipperPIDState(eqx.Module):
    prev_temp: Float[Array, " zones"]     # °C
    deriv: Float[Array, " zones"]         # °C/s, smoothed
    integ: Float[Array, " zones"]         # °C·s
    last_pwm: Float[Array, " zones"]      # duty last sent
    since: Float[Array, " zones"]         # s since it was sent


class KlipperPID(AbstractController):
    """One Klipper `ControlPID` per heater with the config's gains `pid_kp`, `pid_ki`, `pid_kd`
    and its derivative smoothing `smooth_time` (s; a scalar for every heater or one per heater)
    as array leaves (Klipper's units: tuned and exported as they are, one compiled program for
    any values), `max_power` and `ts` (s, the update period) static; `u_hold` (static, per
    heater) the duty a settled loop starts from."""

    pid_kp: Float[Array, " zones"]
    pid_ki: Float[Array, " zones"]
    pid_kd: Float[Array, " zones"]
    smooth_time: Float[Array, " zones"]
    ts: float = eqx.field(static=True, default=1.0)
    max_power: float = eqx.field(static=True, default=1.0)
    u_hold: tuple[float, ...] = eqx.field(static=True, default=())
    pwm_hold: bool = eqx.field(static=True, default=True)

    def __init__(self, pid_kp, pid_ki, pid_kd, *, ts: float = 1.0, max_power: float = 1.0,
                 smooth_time: float = SMOOTH_TIME, u_hold=None, pwm_hold: bool = True):
        g = [jnp.atleast_1d(jnp.asarray(x, float)) for x in (pid_kp, pid_ki, pid_kd)]
        if not (g[0].ndim == 1 and g[0].shape == g[1].shape == g[2].shape):
            raise ControlError("KlipperPID: pid_kp, pid_ki and pid_kd must be 1-D of one length")
        self.pid_kp, self.pid_ki, self.pid_kd = g
        n = int(g[0].shape[0])
        tau = jnp.broadcast_to(jnp.asarray(smooth_time, g[0].dtype), (n,))
        try:
            bad = not bool(np.all(np.asarray(tau) > 0))
        except jax.errors.ConcretizationTypeError:     # built inside a trace: checked outside
            bad = False
        if bad:
            raise ControlError("KlipperPID: smooth_time must be positive")
        self.smooth_time = tau
        self.ts, self.max_power = float(ts), float(max_power)
        hold = np.zeros(n) if u_hold is None else np.broadcast_to(np.asarray(u_hold, float), (n,))
        self.u_hold = tuple(float(v) for v in hold)
        self.pwm_hold = bool(pwm_hold)

    def __check_init__(self):
        if not (self.ts > 0 and 0 < self.max_power <= 1):
            raise ControlError("KlipperPID: needs ts > 0, 0 < max_power <= 1")

    @property
    def zones(self) -> int:
        return int(self.pid_kp.shape[0])

    def _ki(self):
        return self.pid_ki / PID_PARAM_BASE

    def integ_max(self):
        """The integral's clamp, $P_{max}/K_i$ (°C·s; 0 when $K_i = 0$, as Klipper sets it)."""
        ki = self._ki()
        return jnp.where(ki > 0, self.max_power / jnp.where(ki > 0, ki, 1.0), 0.0)

    def init(self, y0, r0) -> KlipperPIDState:
        y0 = jnp.asarray(y0, self.pid_kp.dtype)[:self.zones] + jnp.zeros_like(self.pid_kp)
        r0 = jnp.asarray(r0, self.pid_kp.dtype)[:self.zones] + jnp.zeros_like(self.pid_kp)
        settled = jnp.abs(r0 - y0) < SETTLED_C
        hold = jnp.clip(jnp.asarray(self.u_hold, self.pid_kp.dtype), 0.0, self.max_power)
        ki = self._ki()
        integ = jnp.clip(hold / jnp.where(ki > 0, ki, 1.0), 0.0, self.integ_max())
        z = jnp.zeros_like(self.pid_kp)
        return KlipperPIDState(prev_temp=y0, deriv=z, integ=jnp.where(settled, integ, z),
                               last_pwm=jnp.where(settled, hold, z), since=z + HOLD_S)

    def step(self, state: KlipperPIDState, y, r):
        y = jnp.asarray(y)[:self.zones]
        r = jnp.asarray(r)[:self.zones]
        dt, tau = self.ts, self.smooth_time
        diff = y - state.prev_temp
        deriv = jnp.where(dt >= tau, diff / dt,
                          (state.deriv * jnp.maximum(tau - dt, 0.0) + diff) / tau)
        err = r - y
        integ = jnp.clip(state.integ + err * dt, 0.0, self.integ_max())
        co = (self.pid_kp * err + self.pid_ki * integ - self.pid_kd * deriv) / PID_PARAM_BASE
        value = jnp.clip(co, 0.0, self.max_power)
        integ = jnp.where(co == value, integ, state.integ)
        value = jnp.where(r > 0, value, 0.0)
        since = state.since + dt
        if self.pwm_hold:
            small = jnp.abs(value - state.last_pwm) < MIN_PWM_CHANGE_RATIO * self.max_power
            keep = small & ((since < HOLD_S) | (state.last_pwm == 0))
            value = jnp.where(keep, state.last_pwm, value)
            since = jnp.where(keep, since, 0.0)
        return value, KlipperPIDState(prev_temp=y, deriv=deriv, integ=integ, last_pwm=value,
                                      since=since)

    def gains(self) -> list[dict]:
        """Per heater `{pid_Kp, pid_Ki, pid_Kd, smooth_time}` (Klipper's config units, s)."""
        return [{"pid_Kp": float(a), "pid_Ki": float(b), "pid_Kd": float(c),
                 "smooth_time": float(t)} for a, b, c, t in
                zip(*(np.asarray(x) for x in (self.pid_kp, self.pid_ki, self.pid_kd,
                                              self.smooth_time)))]

    def rounded(self, digits: int = 3) -> KlipperPID:
        """The controller with its gains rounded as they are written to `printer.cfg`
        (`PID_CALIBRATE` writes `%.3f`), so that what is judged is what the printer runs."""
        rnd = [jnp.asarray(np.round(np.asarray(g, np.float64), digits))
               for g in (self.pid_kp, self.pid_ki, self.pid_kd, self.smooth_time)]
        return KlipperPID(*rnd[:3], ts=self.ts, max_power=self.max_power,
                          smooth_time=jnp.maximum(rnd[3], 10.0 ** -digits), u_hold=self.u_hold,
                          pwm_hold=self.pwm_hold)


def from_standard(kp, ti, td, **kw) -> KlipperPID:
    """A Klipper PID from the standard form $K_p (e + \\frac{1}{T_i}\\int e + T_d \\dot e)$ with
    $K_p$ in power fraction per °C: `pid_kp` = 255 $K_p$, `pid_ki` = `pid_kp`/$T_i$,
    `pid_kd` = `pid_kp` $T_d$."""
    kp = PID_PARAM_BASE * np.asarray(kp, np.float64)
    return KlipperPID(kp, kp / np.asarray(ti, np.float64), kp * np.asarray(td, np.float64), **kw)


class Autotune(NamedTuple):
    """`PID_CALIBRATE` on a model: Klipper's final gains (config units), the ultimate gain
    `ku` (duty per °C), the period `tu` (s) it took them from, and every cycle's `(ku, tu)`."""

    pid_kp: float
    pid_ki: float
    pid_kd: float
    ku: float
    tu: float
    cycles: list


def _zn(peaks, pos, max_power):
    amplitude = 0.5 * abs(peaks[pos][0] - peaks[pos - 1][0])
    ku = 4.0 * max_power / (math.pi * amplitude)
    tu = peaks[pos][1] - peaks[pos - 2][1]
    kp = 0.6 * ku * PID_PARAM_BASE
    return kp, kp / (0.5 * tu), kp * 0.125 * tu, ku, tu


def pid_calibrate(model, target: float, loop: int = 0, *, max_power: float = 1.0,
                  max_steps: int = 200_000) -> Autotune:
    """Klipper's `PID_CALIBRATE HEATER=... TARGET=target` run on `model` (a design-point state
    space: its `u0`, `y0` one equilibrium), at the model's sample time, the other heaters held
    at their design input: from the equilibrium with this heater off, full power (`max_power`)
    until the temperature reaches `target`, off until it falls to `target - TUNE_PID_DELTA`,
    and so on; the extreme between two switches is a peak; after 12 peaks, per
    `ControlAutoTune.calc_pid` on peaks $k, k-1, k-2$: amplitude $a = |T_k - T_{k-1}|/2$,
    $K_u = 4 P_{max}/(\\pi a)$, $T_u = t_k - t_{k-2}$, Ziegler–Nichols
    $K_p = 0.6 K_u \\cdot 255$, $T_i = T_u/2$, $T_d = T_u/8$; the final gains from the cycle
    of median period among peaks 4..11 (`calc_final_pid`). `ControlError` when the model never
    reaches the target at full power or does not oscillate within `max_steps` samples."""
    ss = as_state_space(model)
    A, B, C, D = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    u0, y0 = np.asarray(ss.u0, np.float64), np.asarray(ss.y0, np.float64)
    ts = float(ss.ts)
    b, c, d = B[:, loop], C[loop], D[loop, loop]
    du_off = -u0[loop]
    x = np.linalg.solve(np.eye(A.shape[0]) - A, b * du_off)   # at rest with this heater off
    heating, peak, peak_t = False, 0.0, 0.0
    calib, tgt = float(target), float(target)
    peaks: list[tuple[float, float]] = []
    for k in range(max_steps):
        du = (max_power if heating else 0.0) - u0[loop]
        temp = float(y0[loop] + c @ x + d * du)
        t = k * ts
        switched = False
        if heating and temp >= tgt:
            heating, switched = False, True
            tgt = calib - TUNE_PID_DELTA
        elif not heating and temp <= tgt:
            heating, switched = True, True
            tgt = calib
        if switched:
            peaks.append((peak, peak_t))
            peak = 9999999.0 if heating else -9999999.0
            if not heating and len(peaks) >= 12:
                break
        if heating and temp < peak or not heating and temp > peak:
            peak, peak_t = temp, t
        du = (max_power if heating else 0.0) - u0[loop]
        x = A @ x + b * du
    else:
        raise ControlError(f"PID_CALIBRATE on the model: {len(peaks)} of 12 relay peaks within "
                           f"{max_steps * ts:g} s at target {target:g} °C (does full power reach it?)")
    cycles = [_zn(peaks, p, max_power) for p in range(4, len(peaks))]
    times = sorted((peaks[p][1] - peaks[p - 2][1], p) for p in range(4, len(peaks)))
    mid = times[len(times) // 2][1]
    kp, ki, kd, ku, tu = _zn(peaks, mid, max_power)
    if not all(math.isfinite(v) and v > 0 for v in (kp, ki, kd)):
        raise ControlError(f"PID_CALIBRATE on the model: no oscillation at {target:g} °C")
    return Autotune(kp, ki, kd, ku, tu, [(c_[3], c_[4]) for c_ in cycles])


__all__ = [
    "HOLD_S",
    "MIN_PWM_CHANGE_RATIO",
    "PID_PARAM_BASE",
    "SETTLED_C",
    "SMOOTH_TIME",
    "TUNE_PID_DELTA",
    "Autotune",
    "KlipperPID",
    "KlipperPIDState",
    "from_standard",
    "pid_calibrate",
]
