"""The hot-end model that Marlin's and Kalico's model-predictive control run, fitted to a
record as a grey box, and its constants.

**The model** (Marlin `module/temperature.cpp`, `MPC_t`; Kalico `klippy/extras/control_mpc.py`):
a heater block of heat capacity $C$ (J/K) heated by $P u$ ($P$ the heater's power, W; $u$ the
duty) and losing $(A + F_f f)(T_b - T_a)$ to the surroundings at $T_a$ ($A$ the ambient
transfer, W/K; $F_f$ what the part-cooling fan adds at full speed, $f \\in [0, 1]$), and a
sensor that follows the block at the rate $R$ (the sensor responsiveness, K/s per K):

$$C \\dot T_b = P u - (A + F_f f)(T_b - T_a), \\qquad \\dot T_s = R (T_b - T_s).$$

Marlin's `M306 F` and Kalico's `fan_ambient_transfer` take the transfer *with* the fan at full
speed, $A + F_f$; the firmware interpolates in between.

**The fit.** Temperatures fix only the rates: $h = P/C$ (K/s at full duty), $a = A/C$,
$a_f = F_f/C$ (1/s), $R$ and $T_a$; the heater's power $P$ is the user's (its rating:
Marlin's `MPC_HEATER_POWER`, Kalico's required `heater_power`), and sets the scale of $C$, $A$
and $F_f$. The rates are fitted by simulation error (the record's sensor temperature from its
duty and fan, block and sensor starting together at the first reading), exact zero-order hold
per sample, Levenberg–Marquardt (`scipy.optimize.least_squares`) in the logarithms of the
rates (so every rate stays positive: $R > 0$, never the negative responsiveness a fit of
differences can give) from `STARTS` block and sensor time constants, the best kept.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError, ControlError

#: Marlin's default heater power (`Configuration.h`, `MPC_HEATER_POWER`), W
HEATER_POWER_W = 40.0
#: (block time constant, sensor time constant) pairs the fit starts from, s
STARTS = ((150.0, 5.0), (150.0, 20.0), (400.0, 10.0))
#: the rates' names in the fitted parameter vector (logarithms, then T_a)
RATES = ("heating_rate", "ambient_rate", "sensor_responsiveness", "fan_rate")


def _discrete(h, a, R, ts):
    """Exact zero-order hold of block and sensor over `ts` for loss rate `a`: (Phi, Gamma),
    states (T_b - T_a, T_s - T_a), input the duty; through the matrix exponential of the
    augmented 3x3 system."""
    z = jnp.zeros_like(a)
    M = jnp.stack([jnp.stack([-a, z, h]), jnp.stack([R, -R, z]), jnp.stack([z, z, z])])
    E = jax.scipy.linalg.expm(M * ts)
    return E[:2, :2], E[:2, 2]


def _simulate(theta, u, f, ts, x0):
    """The sensor temperature (°C) for log rates and T_a in `theta`, duty `u`, fan `f`."""
    h, a, R, af = (jnp.exp(theta[i]) for i in (0, 1, 2, 4))
    ta = theta[3]
    off = _discrete(h, a, R, ts)
    on = _discrete(h, a + af, R, ts)

    def step(x, uf):
        uk, fk = uf
        Phi = off[0] + fk * (on[0] - off[0])
        Gam = off[1] + fk * (on[1] - off[1])
        return Phi @ x + Gam * uk, x[1]

    x = jnp.stack([x0 - ta, x0 - ta])
    _, ys = jax.lax.scan(step, x, (u, f))
    return ys + ta


_sim = jax.jit(_simulate)
_jac = jax.jit(jax.jacfwd(_simulate))


def fit_two_state(y, u, fan=None, *, ts: float, heater_power: float = HEATER_POWER_W,
                  ambient=None) -> dict:
    """Fit the two-state model to one heater's record (`y` °C, `u` duty, `fan` 0..1 or None)
    at sample time `ts` (s). `ambient`: T_a (°C) when known, else fitted. Returns
    `constants` (`mpc_constants`), `rates`, `ambient_C`, `rms_C` (the simulation error) and
    `fan` (whether the record moved the fan: without, $F_f$ is not identified and left 0).
    `ControlError` when no start converges to finite rates."""
    from scipy.optimize import least_squares

    y, u = np.asarray(y, np.float64).ravel(), np.asarray(u, np.float64).ravel()
    if y.shape != u.shape or y.size < 10 or not (np.all(np.isfinite(y)) and np.all(np.isfinite(u))):
        raise ConfigError("MPC fit: needs at least ten finite samples of one heater")
    f = np.zeros_like(u) if fan is None else np.clip(np.asarray(fan, np.float64).ravel(), 0, 1)
    has_fan = bool(np.ptp(f) > 0.1)
    if np.ptp(u) < 0.05 or np.ptp(y) < 5.0:
        raise ControlError("MPC fit: the record does not move the heater enough (a heat-up "
                           "or a PID_CALIBRATE run identifies it)")
    ta0 = float(min(y[0], 25.0)) if ambient is None else float(ambient)
    slope = np.max(np.diff(y)) / ts
    free = [0, 1, 2] + ([4] if has_fan else []) + ([3] if ambient is None else [])
    best = None
    for tau_b, tau_s in STARTS:
        a0 = 1.0 / tau_b
        h0 = max(slope, 1e-3) * 1.5 / max(float(np.max(u)), 1e-3)
        theta0 = np.array([math.log(h0), math.log(a0), math.log(1.0 / tau_s), ta0,
                           math.log(0.3 * a0)])

        def full(p, theta0=theta0):
            th = theta0.copy()
            th[free] = p
            return th

        def res(p):
            return np.asarray(_sim(full(p), u, f, ts, y[0]), np.float64) - y

        def jac(p):
            return np.asarray(_jac(full(p), u, f, ts, y[0]), np.float64)[:, free]

        try:
            sol = least_squares(res, theta0[free], jac=jac, method="lm", max_nfev=200)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if np.all(np.isfinite(sol.x)) and np.isfinite(sol.cost) and (best is None or
                                                                       sol.cost < best[0]):
            best = (float(sol.cost), full(sol.x))
    if best is None:
        raise ControlError("MPC fit: no start converged to a two-state hot-end model")
    th = best[1]
    h, a, R = (float(np.exp(th[i])) for i in (0, 1, 2))
    af = float(np.exp(th[4])) if has_fan else 0.0
    const = mpc_constants(h, a, R, af, heater_power)
    rms = math.sqrt(2.0 * best[0] / y.size)
    return {"constants": const, "rates": dict(zip(RATES, (h, a, R, af))),
            "ambient_C": float(th[3]), "rms_C": rms, "fan": has_fan}


def simulate(constants: dict, u, fan=None, *, ts: float, ambient: float, y0: float):
    """The sensor temperature the constants give for duty `u` (and `fan`), from rest at `y0`
    (block and sensor together); the fit's own simulation, float64 in NumPy."""
    u = np.asarray(u, np.float64).ravel()
    f = np.zeros_like(u) if fan is None else np.asarray(fan, np.float64).ravel()
    mats = {}
    x = np.full(2, float(y0) - float(ambient))
    out = np.empty_like(u)
    for k, (uk, fk) in enumerate(zip(u, f)):
        key = float(fk)
        if key not in mats:
            ss = mpc_model(constants, ts, ambient, fan=key)
            mats[key] = (np.asarray(ss.A, np.float64), np.asarray(ss.B, np.float64)[:, 0])
        out[k] = x[1] + ambient
        Phi, Gam = mats[key]
        x = Phi @ x + Gam * uk
    return out


def mpc_model(constants: dict, ts: float, ambient: float, fan: float = 0.0):
    """The two-state model as a jthermo state space at `ts` (exact zero-order hold, float64),
    the fan held at `fan`: states $(T_b - T_a, T_s - T_a)$, input the duty, output $T_s$;
    operating point $u_0 = 0$, $y_0 = T_a$."""
    from scipy.linalg import expm

    from ..models._base import StateSpace

    P, Cb, R, A = (float(constants[k]) for k in ("heater_power", "block_heat_capacity",
                                                  "sensor_responsiveness", "ambient_transfer"))
    A = A + float(fan) * (float(constants.get("fan_ambient_transfer", A)) - A)
    Ac = np.array([[-A / Cb, 0.0], [R, -R]])
    Bc = np.array([[P / Cb], [0.0]])
    M = expm(np.block([[Ac, Bc], [np.zeros((1, 3))]]) * ts)
    return StateSpace(M[:2, :2], M[:2, 2:], np.array([[0.0, 1.0]]), ts=ts, u0=np.zeros(1),
                      y0=np.full(1, float(ambient)))


def mpc_constants(heating_rate: float, ambient_rate: float, sensor_rate: float,
                  fan_rate: float, heater_power: float) -> dict:
    """Firmware constants from the fitted rates (module docstring) and the heater's power
    $P$ (W): $C = P/h$, $A = a C$, $R$, and the transfer with the fan at full speed
    $A + a_f C$ (`fan_ambient_transfer`; $A$ when the record never ran the fan)."""
    if not all(math.isfinite(v) and v > 0 for v in (heating_rate, ambient_rate, sensor_rate,
                                                    heater_power)):
        raise ConfigError("MPC constants: the fit is not a heater (its rates and the heater "
                          "power must be positive)")
    if not (math.isfinite(fan_rate) and fan_rate >= 0):
        raise ConfigError("MPC constants: the fan's transfer must be finite and not negative")
    C = heater_power / heating_rate
    return {"heater_power": float(heater_power), "block_heat_capacity": C,
            "sensor_responsiveness": float(sensor_rate), "ambient_transfer": ambient_rate * C,
            "fan_ambient_transfer": (ambient_rate + fan_rate) * C}


__all__ = ["HEATER_POWER_W", "STARTS", "fit_two_state", "mpc_constants", "mpc_model",
           "simulate"]
