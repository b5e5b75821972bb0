"""Controller settings in each firmware's own units and syntax.

- **Klipper** (`klippy/extras/heaters.py`): a `[extruder]` / `[heater_bed]` / `[heater_generic
  NAME]` section with `control: pid`, `pid_Kp`, `pid_Ki`, `pid_Kd` (duty/255 per °C, per °C·s,
  per °C/s: `PID_PARAM_BASE`), `max_power` and `smooth_time` (the derivative smoothing, s), the
  law `pid.KlipperPID` runs.
- **Marlin** (`Marlin/src/gcode/temp/M301.cpp`, `M304.cpp`, `module/temperature.h`):
  `M301 E<n> P I D` (hot end) and `M304 P I D` (bed). The user-facing values are per unit of
  `PID_MAX` (255 = full power) per °C, $I$ per °C·s and $D$ per °C/s; Marlin stores
  $K_i \\cdot$ `PID_dT` and $K_d /$ `PID_dT` and sums the error per temperature-ISR sample, so
  with `PID_MAX` = 255 the numbers are Klipper's. Its derivative is filtered differently (a
  first-order filter, `PID_K1` = 0.95 per `PID_dT`) and it leaves PID control more than
  `PID_FUNCTIONAL_RANGE` from the target: the file says so.
- **Marlin MPC** (`M306.cpp`): `M306 E<n> P<W> C<J/K> R<K/s/K> A<W/K> F<W/K>`, the constants
  of the two-state block + sensor model (`mpc.mpc_model`); **Kalico** (`docs/MPC.md`):
  `control: mpc` with `heater_power`, `block_heat_capacity`, `sensor_responsiveness`,
  `ambient_transfer`, `fan_ambient_transfer`.
- **C**: the same Klipper law as a self-contained C function with the gains compiled in
  (`smooth_time` among them).

Every file starts with the calibration's note (a comment), which says first when the result
is not a tuning to use.
"""

from __future__ import annotations

import math

from ..errors import ConfigError
from .pid import HOLD_S, MIN_PWM_CHANGE_RATIO, PID_PARAM_BASE, KlipperPID

#: the file each firmware's settings go to, in the output folder
FILE_NAMES = {"klipper": "firmware.cfg", "kalico": "firmware.cfg", "marlin": "firmware.gcode",
              "c": "firmware.c"}


def section_name(heater: str) -> str:
    """Klipper's section for a heater's Stats name: `extruder*`, `heater_bed`, else
    `heater_generic NAME`."""
    if heater.startswith("extruder") or heater == "heater_bed":
        return heater
    return f"heater_generic {heater}"


def _f(v: float) -> str:
    if not math.isfinite(v):
        raise ConfigError("firmware settings: a gain is not finite")
    return f"{v:.3f}"


def klipper_cfg(ctrl: KlipperPID, heaters, note: str = "") -> str:
    """`printer.cfg` lines: one section per heater (`heaters`: Stats names, one per loop)."""
    heaters = list(heaters)
    if len(heaters) != ctrl.zones:
        raise ConfigError(f"firmware settings: {len(heaters)} heater names for {ctrl.zones} loops")
    out = [f"# {line}" for line in note.splitlines()] if note else []
    for h, g in zip(heaters, ctrl.gains()):
        out += [f"[{section_name(h)}]", "control: pid", f"pid_Kp: {_f(g['pid_Kp'])}",
                f"pid_Ki: {_f(g['pid_Ki'])}", f"pid_Kd: {_f(g['pid_Kd'])}",
                f"max_power: {ctrl.max_power:g}", f"smooth_time: {g['smooth_time']:g}", ""]
    return "\n".join(out)


def marlin_gcode(ctrl: KlipperPID, heaters, note: str = "", mpc: dict | None = None) -> str:
    """`M301` / `M304` lines (then `M500` to store them), Marlin's units with `PID_MAX` 255;
    a hot end with MPC constants (`mpc`: {heater: constants}) gets its `M306` line as a
    commented-out alternative (for a firmware built with `MPCTEMP`)."""
    out = [f"; {line}" for line in note.splitlines()] if note else []
    out += [("; Marlin's derivative is filtered by PID_K1 = 0.95 per PID_dT and its PID acts only "
            "within PID_FUNCTIONAL_RANGE of the target; these gains were tuned under Klipper's law "
            "with the same units (PID_MAX = 255).")]
    taus = ", ".join(f"{h} {g['smooth_time']:g} s" for h, g in zip(heaters, ctrl.gains()))
    out.append(f"; the tuning's derivative smoothing (Klipper's smooth_time: {taus}) has no M301 / "
               "M304 setting: Marlin keeps its fixed PID_K1 filter.")
    e = 0
    for h, g in zip(heaters, ctrl.gains()):
        gains = f"P{_f(g['pid_Kp'])} I{_f(g['pid_Ki'])} D{_f(g['pid_Kd'])}"
        if "bed" in h:
            out.append(f"M304 {gains} ; {h}")
        else:
            out.append(f"M301 E{e} {gains} ; {h}")
            if h in (mpc or {}):
                out.append(f"; with MPCTEMP instead of PIDTEMP: {marlin_mpc(mpc[h], e)}")
            e += 1
    if ctrl.max_power < 1.0:
        out.append(f"; max_power {ctrl.max_power:g}: set MAX_BED_POWER / PID_MAX to "
                   f"{round(255 * ctrl.max_power)} in Configuration.h")
    out.append("M500")
    return "\n".join(out) + "\n"


#: significant digits of the MPC constants written: enough that the constants read back
#: reproduce the fitted model's step response to 1e-6 °C (the firmware itself keeps floats)
MPC_DIGITS = 10


def _g(v: float) -> str:
    if not math.isfinite(v):
        raise ConfigError("firmware settings: an MPC constant is not finite")
    return f"{v:.{MPC_DIGITS}g}"


def kalico_cfg(ctrl: KlipperPID, heaters, mpc: dict | None = None, note: str = "") -> str:
    """Kalico runs Klipper's `control: pid` unchanged; a hot end with MPC constants (`mpc`:
    {heater: constants}) gets a commented-out `control: mpc` alternative with Kalico's keys
    (`docs/MPC.md`: `heater_power` W, `block_heat_capacity` J/K, `sensor_responsiveness`
    K/s/K, `ambient_transfer` W/K, `fan_ambient_transfer` W/K at fan speeds 0 and 1, with
    `cooling_fan: fan`)."""
    text = klipper_cfg(ctrl, heaters, note)
    for h, c in (mpc or {}).items():
        lines = [f"# [{section_name(h)}] as Kalico's model-predictive control instead:",
                 "# control: mpc", f"# heater_power: {_g(c['heater_power'])}",
                 f"# block_heat_capacity: {_g(c['block_heat_capacity'])}",
                 f"# sensor_responsiveness: {_g(c['sensor_responsiveness'])}",
                 f"# ambient_transfer: {_g(c['ambient_transfer'])}"]
        if c.get("fan_ambient_transfer", c["ambient_transfer"]) != c["ambient_transfer"]:
            pair = f"{_g(c['ambient_transfer'])}, {_g(c['fan_ambient_transfer'])}"
            lines += ["# cooling_fan: fan", f"# fan_ambient_transfer: {pair}"]
        text += "\n" + "\n".join(lines) + "\n"
    return text


def marlin_mpc(constants: dict, e: int = 0) -> str:
    """`M306 E P C R A F` (`gcode/temp/M306.cpp`; Marlin's units: W, J/K, K/s/K, W/K, and F the
    ambient transfer with the fan at full speed, W/K: Marlin keeps `F - A` as
    `fan255_adjustment`)."""
    c = constants
    return (f"M306 E{e} P{_g(c['heater_power'])} C{_g(c['block_heat_capacity'])} "
            f"R{_g(c['sensor_responsiveness'])} A{_g(c['ambient_transfer'])} "
            f"F{_g(c.get('fan_ambient_transfer', c['ambient_transfer']))}")


def c_source(ctrl: KlipperPID, name: str = "jthermo_heater", note: str = "") -> str:
    """Klipper's law in C (one state struct per heater, `*_update` once per reading); `note`
    (e.g. that it is not a tuning to use) heads the file as a comment."""
    g = ctrl.gains()
    n = len(g)
    arr = lambda k: ", ".join(repr(float(x[k])) for x in g)
    head = "".join(f"/* {line.replace('*/', '* /')} */\n" for line in note.splitlines())
    return head + f"""/* Klipper's heater PID (klippy/extras/heaters.py, ControlPID), tuned by jthermo.
 * Call {name}_update(state, i, dt, temp, target) once per sensor reading; returns the duty. */
#include <math.h>
#define {name.upper()}_N {n}
static const double {name}_kp[{n}] = {{{arr('pid_Kp')}}};
static const double {name}_ki[{n}] = {{{arr('pid_Ki')}}};
static const double {name}_kd[{n}] = {{{arr('pid_Kd')}}};
static const double {name}_smooth[{n}] = {{{arr('smooth_time')}}};
static const double {name}_max_power = {ctrl.max_power!r};
typedef struct {{ double prev_temp, deriv, integ, last_pwm, since; }} {name}_state;

double {name}_update({name}_state *s, int i, double dt, double temp, double target) {{
    const double base = {PID_PARAM_BASE!r};
    double kp = {name}_kp[i] / base, ki = {name}_ki[i] / base, kd = {name}_kd[i] / base;
    double imax = ki > 0 ? {name}_max_power / ki : 0.0;
    double diff = temp - s->prev_temp, deriv, err = target - temp, integ, co, v;
    double tau = {name}_smooth[i];
    deriv = dt >= tau ? diff / dt : (s->deriv * (tau - dt) + diff) / tau;
    integ = fmin(fmax(s->integ + err * dt, 0.0), imax);
    co = kp * err + ki * integ - kd * deriv;
    v = fmin(fmax(co, 0.0), {name}_max_power);
    if (co == v) s->integ = integ;
    if (target <= 0) v = 0.0;
    s->since += dt;
    if (fabs(v - s->last_pwm) < {MIN_PWM_CHANGE_RATIO!r} * {name}_max_power
        && (s->since < {HOLD_S!r} || s->last_pwm == 0.0)) v = s->last_pwm;
    else {{ s->last_pwm = v; s->since = 0.0; }}
    s->prev_temp = temp;
    s->deriv = deriv;
    return v;
}}
"""


__all__ = ["FILE_NAMES", "MPC_DIGITS", "c_source", "kalico_cfg", "klipper_cfg", "marlin_gcode",
           "marlin_mpc", "section_name"]
