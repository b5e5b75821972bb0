"""Independent re-implementations, in plain Python floats, of what the tests compare jthermo
against: Klipper's heater PID (`klippy/extras/heaters.py`: `ControlPID.temperature_update`
and `Heater.set_pwm`), Kalico's model-predictive control (`klippy/extras/control_mpc.py`:
`ControlMPC.temperature_update`), a linear plant stepped sample by sample, and a `klippy.log` writer."""

from __future__ import annotations

import numpy as np

BASE = 255.0          # heaters.py PID_PARAM_BASE
MIN_CHANGE = 0.05     # heaters.py MIN_PWM_CHANGE_RATIO
PWM_DELAY = 0.3       # an ADC sensor's report time
MAX_HEAT_TIME = 3.0


class KlipperHeater:
    """One heater: the PID state and the pwm caching of `Heater`, as Klipper keeps them."""

    def __init__(self, kp, ki, kd, max_power=1.0, smooth_time=1.0):
        self.Kp, self.Ki, self.Kd = kp / BASE, ki / BASE, kd / BASE
        self.max_power = max_power
        self.min_deriv_time = smooth_time
        self.temp_integ_max = max_power / self.Ki if self.Ki else 0.0
        self.min_pwm_change = max_power * MIN_CHANGE
        self.prev_temp = 25.0
        self.prev_temp_time = 0.0
        self.prev_temp_deriv = 0.0
        self.prev_temp_integ = 0.0
        self.next_pwm_time = 0.0
        self.last_pwm_value = 0.0

    def settle(self, read_time, temp, duty):
        """Start as a loop that has been holding `temp` with `duty`."""
        self.prev_temp, self.prev_temp_time = temp, read_time
        self.prev_temp_integ = min(duty / self.Ki, self.temp_integ_max)
        self.last_pwm_value = duty
        self.next_pwm_time = read_time - 1.0

    def set_pwm(self, read_time, value, target):
        if target <= 0.0:
            value = 0.0
        if ((read_time < self.next_pwm_time or not self.last_pwm_value)
                and abs(value - self.last_pwm_value) < self.min_pwm_change):
            return
        pwm_time = read_time + PWM_DELAY
        self.next_pwm_time = pwm_time + MAX_HEAT_TIME - (3.0 * PWM_DELAY + 0.001)
        self.last_pwm_value = value

    def update(self, read_time, temp, target):
        time_diff = read_time - self.prev_temp_time
        temp_diff = temp - self.prev_temp
        if time_diff >= self.min_deriv_time:
            temp_deriv = temp_diff / time_diff
        else:
            temp_deriv = (self.prev_temp_deriv * (self.min_deriv_time - time_diff)
                          + temp_diff) / self.min_deriv_time
        temp_err = target - temp
        temp_integ = self.prev_temp_integ + temp_err * time_diff
        temp_integ = max(0.0, min(self.temp_integ_max, temp_integ))
        co = self.Kp * temp_err + self.Ki * temp_integ - self.Kd * temp_deriv
        bounded_co = max(0.0, min(self.max_power, co))
        self.set_pwm(read_time, bounded_co, target)
        self.prev_temp = temp
        self.prev_temp_time = read_time
        self.prev_temp_deriv = temp_deriv
        if co == bounded_co:
            self.prev_temp_integ = temp_integ
        return self.last_pwm_value


class KalicoMPCHeater:
    """One heater under Kalico's `ControlMPC.temperature_update` (`control_mpc.py`, no fan,
    no extrusion) and `Heater.set_pwm`, in the firmware's variable names and order."""

    AMBIENT_TEMP = 25.0

    def __init__(self, heater_power, block_heat_capacity, sensor_responsiveness,
                 ambient_transfer, max_power=1.0, target_reach_time=2.0, smoothing=0.83,
                 min_ambient_change=1.0, steady_state_rate=0.5, temp=25.0):
        self.const_heater_power = heater_power
        self.const_block_heat_capacity = block_heat_capacity
        self.const_sensor_responsiveness = sensor_responsiveness
        self.const_ambient_transfer = ambient_transfer
        self.const_target_reach_time = target_reach_time
        self.const_smoothing = smoothing
        self.const_min_ambient_change = min_ambient_change
        self.const_steady_state_rate = steady_state_rate
        self.heater_max_power = max_power * heater_power
        self.state_block_temp = temp
        self.state_sensor_temp = temp
        self.state_ambient_temp = self.AMBIENT_TEMP
        self.last_power = 0.0
        self.last_temp_time = 0.0
        self.next_pwm_time = 0.0
        self.last_pwm_value = 0.0
        self.target_temp = 0.0

    def settle(self, read_time, temp, duty):
        """Start as a loop that has been holding `temp` with `duty` (jthermo's settled start)."""
        self.state_block_temp = self.state_sensor_temp = temp
        self.last_power = duty * self.const_heater_power
        self.state_ambient_temp = temp - self.last_power / self.const_ambient_transfer
        self.last_pwm_value = duty
        self.last_temp_time = read_time
        self.next_pwm_time = read_time - 1.0

    def set_pwm(self, read_time, value):
        if self.target_temp <= 0.0:
            value = 0.0
        if ((read_time < self.next_pwm_time or not self.last_pwm_value)
                and abs(value - self.last_pwm_value) < 0.05):
            return
        pwm_time = read_time + PWM_DELAY
        self.next_pwm_time = pwm_time + MAX_HEAT_TIME - (3.0 * PWM_DELAY + 0.001)
        self.last_pwm_value = value

    def update(self, read_time, temp, target_temp):
        self.target_temp = target_temp
        dt = read_time - self.last_temp_time
        if self.last_temp_time == 0.0 or dt < 0.0 or dt > 1.0:
            dt = 0.1
        ambient_transfer = self.const_ambient_transfer
        expected_heating = self.last_power
        block_ambient_delta = self.state_block_temp - self.state_ambient_temp
        expected_ambient_transfer = block_ambient_delta * ambient_transfer
        expected_block_dT = ((expected_heating - expected_ambient_transfer) * dt
                             / self.const_block_heat_capacity)
        self.state_block_temp += expected_block_dT
        expected_sensor_dT = ((self.state_block_temp - self.state_sensor_temp)
                              * self.const_sensor_responsiveness * dt)
        self.state_sensor_temp += expected_sensor_dT
        smoothing = 1 - (1 - self.const_smoothing) ** dt
        adjustment_dT = (temp - self.state_sensor_temp) * smoothing
        self.state_block_temp += adjustment_dT
        self.state_sensor_temp += adjustment_dT
        if (0 < self.last_power < 1.0) or abs(
                expected_block_dT + adjustment_dT) < self.const_steady_state_rate * dt:
            if adjustment_dT > 0.0:
                ambient_delta = max(adjustment_dT, self.const_min_ambient_change * dt)
            else:
                ambient_delta = min(adjustment_dT, -self.const_min_ambient_change * dt)
            self.state_ambient_temp += ambient_delta
        heating_power = ((target_temp - self.state_block_temp) * self.const_block_heat_capacity
                         / self.const_target_reach_time)
        loss_ambient = (self.state_block_temp - self.state_ambient_temp) * ambient_transfer
        if target_temp != 0.0:
            power = max(0.0, min(self.heater_max_power, heating_power + loss_ambient))
        else:
            power = 0
        duty = power / self.const_heater_power
        self.last_power = power
        self.last_temp_time = read_time
        self.set_pwm(read_time, duty)
        return self.last_pwm_value


def closed_loop(A, B, C, u0, y0, heater, r, x0, ts, noise=None, duty0=None, t0=0.0):
    """A heater's controller (`update(read_time, temp, target)`) on the plant
    $x_{k+1} = A x_k + B (u_k - u_0)$, $y_k = y_0 + C x_k$ (one heater), one update per
    sample from time `t0`: returns the measured temperatures and the duties."""
    x = np.array(x0, float)
    ys, us = [], []
    for k in range(len(r)):
        y = float(y0 + C @ x) + (0.0 if noise is None else float(noise[k]))
        if k == 0 and duty0 is not None:
            heater.settle(t0 - ts, y, duty0)
        u = heater.update(t0 + k * ts, y, float(r[k]))
        ys.append(y)
        us.append(u)
        x = A @ x + B * (u - u0)
    return np.array(ys), np.array(us)


STATS_PAD = ("gcodein=0  mcu: mcu_awake=0.001 mcu_task_avg=0.000010 mcu_task_stddev=0.000007 "
             "bytes_write=1 bytes_read=2 freq=71999976 ")


def config_dump(heaters: dict) -> list[str]:
    out = ["===== Config file =====", "[printer]", "kinematics = cartesian", ""]
    for name, opts in heaters.items():
        out.append(f"[{name}]")
        out += [f"{k} = {v}" for k, v in opts.items()]
        out.append("")
    out.append("=======================")
    return out


def stats_line(clock: float, values: dict) -> str:
    """`values`: {heater: (target, temp, pwm)} in Klipper's print formats."""
    parts = [f"{h}: target={t:.0f} temp={y:.1f} pwm={u:.3f}" for h, (t, y, u) in values.items()]
    return f"Stats {clock:.1f}: {STATS_PAD}" + " sysload=0.5 cputime=1.0 ".join(parts)


def simulated_log(path, *, seconds=(700, 400), heaters=("extruder", "heater_bed"), seed=0,
                  gains=((22.0, 1.1, 110.0), (60.0, 1.5, 600.0)), gap_after=None,
                  truncate=False, bed_max_power=0.8):
    """A klippy.log of two host runs (a restart between them) of a hot end and a bed under
    Klipper's PID: heat-up from ambient, set-point changes, 0.1 °C / 0.001 printing, the
    Stats clock stepping 1.0 s or 1.1 s; `gap_after` (s into the first run): a 10 s hole in
    the Stats lines. `truncate`: the last line cut inside a heater's fields. Returns
    `{heater: (gain, tau_block, tau_sensor)}` of the plants."""
    rng = np.random.default_rng(seed)
    plants = {"extruder": (250.0, 120.0, 6.0), "heater_bed": (60.0, 400.0, 20.0)}
    cfg = {"extruder": {"heater_pin": "PA1", "sensor_type": "Generic 3950", "control": "pid",
                        "pid_kp": gains[0][0], "pid_ki": gains[0][1], "pid_kd": gains[0][2],
                        "min_temp": 0, "max_temp": 280},
           "heater_bed": {"heater_pin": "PA2", "sensor_type": "Generic 3950", "control": "pid",
                          "pid_kp": gains[1][0], "pid_ki": gains[1][1], "pid_kd": gains[1][2],
                          "max_power": bed_max_power, "min_temp": 0, "max_temp": 120}}
    lines = ["Starting Klippy...", "Git version: 'v0.12.0-1-gabcdef'"]
    clock = 100.0
    for run, dur in enumerate(seconds):
        lines += ["Start printer at Mon Jan  1 00:00:00 2024 (1.0 2.0)"]
        lines += config_dump({h: cfg[h] for h in heaters})
        state = {}
        for h in heaters:
            K, tb, tsn = plants[h]
            mp = 1.0 if h == "extruder" else bed_max_power
            ctl = KlipperHeater(cfg[h]["pid_kp"], cfg[h]["pid_ki"], cfg[h]["pid_kd"],
                                max_power=mp)
            state[h] = [np.array([0.0, 0.0]) if run == 0 else np.array([40.0, 40.0]), ctl, K, tb, tsn]
        t_run = 0.0
        k = 0
        while t_run < dur:
            vals = {}
            for h in heaters:
                x, ctl, K, tb, tsn = state[h]
                hot = 200.0 if h == "extruder" else 60.0
                target = 0.0 if t_run < 10 else hot + (10.0 if (t_run // 150) % 2 else 0.0)
                temp = 22.0 + x[1] + rng.normal(0, 0.05)
                temp = 0.0 if k == 0 else round(temp, 1)
                u = ctl.update(clock, temp, target) if temp else 0.0
                vals[h] = (target, temp, u)
            if not (gap_after is not None and run == 0 and gap_after <= t_run < gap_after + 10):
                lines.append(stats_line(clock, vals))
            step = 1.1 if rng.random() < 0.05 else 1.0
            for h in heaters:
                x, ctl, K, tb, tsn = state[h]
                u = vals[h][2]
                for _ in range(10):             # the plant between two lines, 10 sub-steps
                    dtb = (K * u - x[0]) / tb
                    dts = (x[0] - x[1]) / tsn
                    x = x + (step / 10) * np.array([dtb, dts])
                state[h][0] = x
            clock = round(clock + step, 1)
            t_run += step
            k += 1
        lines += ["Restarting printer"]
        clock += 5.0
    text = "\n".join(lines) + "\n"
    if truncate:
        text = text.rstrip("\n")
        text = text[: text.rindex("pwm=") + 6]
    with open(path, "w") as f:
        f.write(text)
    return plants
