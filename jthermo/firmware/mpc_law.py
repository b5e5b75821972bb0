"""The model-predictive heater control Kalico runs (`klippy/extras/control_mpc.py`,
`ControlMPC.temperature_update`, and `Heater.set_pwm` of `klippy/extras/heaters.py`) as a
jthermo controller, with the constants `calibrate` exports (`mpc.mpc_constants`).

**Kalico's law**, per heater, at each temperature update (period $\\Delta t$; the firmware takes
0.1 s for its first update and for any gap above 1 s), with the constants $P$ (W), $C$ (J/K),
$R$ (1/s), $A$ (W/K) and its settings `target_reach_time` $t_r$, `smoothing` $s$,
`steady_state_rate` $q$, `min_ambient_change` $m$:

1. *predict* the block and sensor from the power last asked for, $p_{k-1}$ (W):
   $\\delta_b = (p_{k-1} - A (T_b - T_a)) \\Delta t / C$, $T_b \\mathrel{+}= \\delta_b$, then
   $T_s \\mathrel{+}= R (T_b - T_s) \\Delta t$;
2. *correct* both by the measured error, smoothed: $\\sigma = 1 - (1 - s)^{\\Delta t}$,
   $\\delta = \\sigma (T - T_s)$, $T_b \\mathrel{+}= \\delta$, $T_s \\mathrel{+}= \\delta$;
3. *learn the ambient* when the loop is near a steady state, $0 < p_{k-1} < 1$ (Kalico compares
   the power in watts with 1; Marlin the duty with its limits) or
   $|\\delta_b + \\delta| < q \\Delta t$: $T_a \\mathrel{+}= \\max(\\delta, m \\Delta t)$ for
   $\\delta > 0$, else $\\min(\\delta, -m \\Delta t)$;
4. *output* the power that reaches the target in $t_r$ and holds it against the loss:
   $p_k = \\mathrm{clip}((r - T_b) C / t_r + A (T_b - T_a), 0, P_{max} P)$ ($0$ while the
   target is 0), the duty $p_k / P$, sent under `Heater.set_pwm`'s update suppression (a
   change below `MIN_PWM_CHANGE` is not sent unless `pid.HOLD_S` passed, or from 0).

Marlin's `MPCTEMP` (`module/temperature.cpp`) runs the same predict-correct-output steps at its
temperature interrupt's `MPC_dT` with a fixed smoothing per step and the same 2 s reach time.
The fan's transfer and the filament feed-forward are left out: the closed loops here run the
fan's load as a disturbance the controller does not see (the firmware reads the fan speed).

The loop starts (`init`) with block and sensor at the first reading; settled (within
`pid.SETTLED_C` of the target) it starts holding the design's duty `u_hold`: its last power
$P u$ and the ambient that power holds, $T_a = T - P u / A$; from further away (a cold start)
at rest with the last power 0 and the ambient at Kalico's `AMBIENT_TEMP`, 25 °C.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..control._base import AbstractController
from ..errors import ControlError
from .pid import HOLD_S, SETTLED_C

#: Kalico's defaults (`heaters.py` profile keys): s, per second, °C/s, °C/s
TARGET_REACH_TIME, SMOOTHING, STEADY_STATE_RATE, MIN_AMBIENT_CHANGE = 2.0, 0.83, 0.5, 1.0
#: `control_mpc.py`: the ambient the model starts from without an ambient sensor, °C
AMBIENT_TEMP = 25.0
#: `Heater.set_pwm` in Kalico: duty changes below this are suppressed (absolute)
MIN_PWM_CHANGE = 0.05
#: the firmware's update period when it has no previous reading, or the gap is above `MAX_DT`
FIRST_DT, MAX_DT = 0.1, 1.0


class FirmwareMPCState(eqx.Module):
    block: Float[Array, " zones"]          # modelled block temperature, °C
    sensor: Float[Array, " zones"]         # modelled sensor temperature, °C
    ambient: Float[Array, " zones"]        # modelled ambient, °C
    power: Float[Array, " zones"]          # power last asked for, W
    last_pwm: Float[Array, " zones"]       # duty last sent
    since: Float[Array, " zones"]          # s since it was sent
    started: Float[Array, " zones"]        # 1 after the first update (Kalico's last_temp_time)


class FirmwareMPC(AbstractController):
    """Kalico's `control: mpc` per heater (module docstring) with the constants `heater_power`
    (W), `block_heat_capacity` (J/K), `sensor_responsiveness` (1/s) and `ambient_transfer`
    (W/K) as array leaves; `ts` (s, the update period), `max_power` and the firmware's
    settings static; `u_hold` (per heater) the duty a settled loop starts from."""

    heater_power: Float[Array, " zones"]
    block_heat_capacity: Float[Array, " zones"]
    sensor_responsiveness: Float[Array, " zones"]
    ambient_transfer: Float[Array, " zones"]
    ts: float = eqx.field(static=True, default=1.0)
    max_power: float = eqx.field(static=True, default=1.0)
    target_reach_time: float = eqx.field(static=True, default=TARGET_REACH_TIME)
    smoothing: float = eqx.field(static=True, default=SMOOTHING)
    steady_state_rate: float = eqx.field(static=True, default=STEADY_STATE_RATE)
    min_ambient_change: float = eqx.field(static=True, default=MIN_AMBIENT_CHANGE)
    u_hold: tuple[float, ...] = eqx.field(static=True, default=())

    def __init__(self, heater_power, block_heat_capacity, sensor_responsiveness,
                 ambient_transfer, *, ts: float = 1.0, max_power: float = 1.0,
                 target_reach_time: float = TARGET_REACH_TIME, smoothing: float = SMOOTHING,
                 steady_state_rate: float = STEADY_STATE_RATE,
                 min_ambient_change: float = MIN_AMBIENT_CHANGE, u_hold=None):
        c = [np.atleast_1d(np.asarray(x, np.float64)) for x in
             (heater_power, block_heat_capacity, sensor_responsiveness, ambient_transfer)]
        n = max(v.size for v in c)
        c = [np.broadcast_to(v, (n,)) for v in c]
        if not all(v.ndim == 1 and np.all(np.isfinite(v)) for v in c) or not (
                np.all(c[0] > 0) and np.all(c[1] > 0) and np.all(c[2] > 0) and np.all(c[3] >= 0)):
            raise ControlError("FirmwareMPC: the constants must be finite, P, C and R positive, "
                               "A not negative")
        (self.heater_power, self.block_heat_capacity, self.sensor_responsiveness,
         self.ambient_transfer) = (jnp.asarray(v) for v in c)
        self.ts, self.max_power = float(ts), float(max_power)
        self.target_reach_time, self.smoothing = float(target_reach_time), float(smoothing)
        self.steady_state_rate = float(steady_state_rate)
        self.min_ambient_change = float(min_ambient_change)
        hold = np.zeros(n) if u_hold is None else np.broadcast_to(np.asarray(u_hold, float), (n,))
        self.u_hold = tuple(float(v) for v in hold)

    def __check_init__(self):
        if not (self.ts > 0 and 0 < self.max_power <= 1 and self.target_reach_time > 0
                and 0 < self.smoothing <= 1 and self.steady_state_rate > 0
                and self.min_ambient_change > 0):
            raise ControlError("FirmwareMPC: needs ts > 0, 0 < max_power <= 1, 0 < smoothing "
                               "<= 1 and positive reach time, steady-state rate, ambient change")

    @classmethod
    def from_constants(cls, constants: dict, **kw) -> FirmwareMPC:
        """From `mpc.mpc_constants`' dict (one heater) or a list of them."""
        cs = [constants] if isinstance(constants, dict) else list(constants)
        keys = ("heater_power", "block_heat_capacity", "sensor_responsiveness",
                "ambient_transfer")
        return cls(*([float(c[k]) for c in cs] for k in keys), **kw)

    @property
    def zones(self) -> int:
        return int(self.heater_power.shape[0])

    def init(self, y0, r0) -> FirmwareMPCState:
        dt = self.heater_power.dtype
        y0 = jnp.asarray(y0, dt)[:self.zones] + jnp.zeros_like(self.heater_power)
        r0 = jnp.asarray(r0, dt)[:self.zones] + jnp.zeros_like(self.heater_power)
        settled = jnp.abs(r0 - y0) < SETTLED_C
        hold = jnp.clip(jnp.asarray(self.u_hold, dt), 0.0, self.max_power)
        p_hold = hold * self.heater_power
        a = self.ambient_transfer
        amb_hold = y0 - p_hold / jnp.where(a > 0, a, 1.0)
        z = jnp.zeros_like(y0)
        return FirmwareMPCState(block=y0, sensor=y0,
                                ambient=jnp.where(settled & (a > 0), amb_hold, AMBIENT_TEMP + z),
                                power=jnp.where(settled, p_hold, z),
                                last_pwm=jnp.where(settled, hold, z), since=z + HOLD_S,
                                started=jnp.where(settled, 1.0, 0.0) + z)

    def step(self, state: FirmwareMPCState, y, r):
        y = jnp.asarray(y)[:self.zones]
        r = jnp.asarray(r)[:self.zones]
        P, C = self.heater_power, self.block_heat_capacity
        R, A = self.sensor_responsiveness, self.ambient_transfer
        ts = self.ts if self.ts <= MAX_DT else FIRST_DT
        dt = jnp.where(state.started > 0, ts, FIRST_DT)
        d_block = (state.power - (state.block - state.ambient) * A) * dt / C
        block = state.block + d_block
        sensor = state.sensor + (block - state.sensor) * R * dt
        adj = (y - sensor) * (1.0 - (1.0 - self.smoothing) ** dt)
        block, sensor = block + adj, sensor + adj
        steady = ((state.power > 0) & (state.power < 1.0)) | (
            jnp.abs(d_block + adj) < self.steady_state_rate * dt)
        step_a = jnp.where(adj > 0, jnp.maximum(adj, self.min_ambient_change * dt),
                           jnp.minimum(adj, -self.min_ambient_change * dt))
        ambient = jnp.where(steady, state.ambient + step_a, state.ambient)
        want = (r - block) * C / self.target_reach_time + (block - ambient) * A
        power = jnp.where(r != 0, jnp.clip(want, 0.0, self.max_power * P), 0.0)
        value = jnp.where(r > 0, power / P, 0.0)
        since = state.since + self.ts
        small = jnp.abs(value - state.last_pwm) < MIN_PWM_CHANGE
        keep = small & ((since < HOLD_S) | (state.last_pwm == 0))
        value = jnp.where(keep, state.last_pwm, value)
        since = jnp.where(keep, since, 0.0)
        return value, FirmwareMPCState(block=block, sensor=sensor, ambient=ambient, power=power,
                                       last_pwm=value, since=since,
                                       started=jnp.ones_like(state.started))

    def constants(self) -> list[dict]:
        """Per heater the firmware's keys (`mpc.mpc_constants` names), W, J/K, 1/s, W/K."""
        keys = ("heater_power", "block_heat_capacity", "sensor_responsiveness",
                "ambient_transfer")
        vals = [np.asarray(getattr(self, k)) for k in keys]
        return [{k: float(v[i]) for k, v in zip(keys, vals)} for i in range(self.zones)]


__all__ = ["AMBIENT_TEMP", "MIN_AMBIENT_CHANGE", "MIN_PWM_CHANGE", "SMOOTHING",
           "STEADY_STATE_RATE", "TARGET_REACH_TIME", "FirmwareMPC", "FirmwareMPCState"]
