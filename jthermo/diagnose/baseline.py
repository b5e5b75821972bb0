"""The diagnosis baseline in NumPy: each zone's first-order model, fitted and simulated on the host.

The baseline of `select.diagnose` is the mechanism library's model with every mechanism off
(`mechanisms.simulate_zone` with `on = 0`): per zone

$$ x_{k+1} = e^{-a t_s} x_k + \\frac{1 - e^{-a t_s}}{a}\\,(b^\\top u_{k-d} + a\\,T_s), \\qquad x_0 \\text{ fitted}, $$

(exact zero-order hold; $u_{k-d}$ the input after a dead time of $d$ samples, interpolated
between the two samples around it as `mechanisms.delayed_inputs` does, $d = 0$ for the fit). Its
simulation error is linear in $b \\ge 0$, $x_0$ and (when the surroundings are not measured)
$T_s$, so the fit is the grey-box identification's variable projection
(`jthermo.identify.greybox.fit_first_order_zones`: NNLS for the linear part, a grid then Brent
on $\\log a$), the optimum the compiled Levenberg–Marquardt (`fitting.fit_zones`) iterated
towards; nothing is compiled.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from ..identify.greybox import fit_first_order_zones
from .mechanisms import PAD, Layout

#: an input at or below this counts as off (as `mechanisms._safe_pow` treats it)
U_OFF = 1e-12


def held(u, u_pad, delay):
    """Inputs `(T, nu)` after a dead time of `delay` samples ($\\ge 0$, any fraction), the samples
    before the record at `u_pad`: $(1 - f) u_{k-i} + f u_{k-i-1}$, $d = i + f$."""
    d = float(np.clip(delay, 0.0, PAD - 2.0))
    i = int(np.floor(d))
    f = d - i
    T = u.shape[0]
    up = np.concatenate([np.broadcast_to(u_pad, (PAD, u.shape[1])), u], axis=0)
    return (1.0 - f) * up[PAD - i:PAD - i + T] + f * up[PAD - i - 1:PAD - i - 1 + T]


def fit(theta0, y, u, ts: float, level: float, ts_free: float, lay: Layout) -> np.ndarray:
    """Baseline parameters `(n, P)`: `theta0` with each zone's `log_a`, `log_b`, `x0` (and
    `ts0`, the surroundings' offset from `level` °C, when `ts_free`) at their least-squares
    optimum; every other entry as in `theta0`."""
    ue = np.where(u > U_OFF, u, 0.0)
    zones = fit_first_order_zones(np.asarray(y, float), ue, ts, surroundings=None if ts_free else level)
    th = np.array(theta0, float)
    for i, z in enumerate(zones):
        th[i, lay.sl("log_a")] = z["log_loss"]
        th[i, lay.sl("log_b")] = z["log_gain"]
        th[i, lay.sl("x0")] = z["c"][0]
        if ts_free:
            th[i, lay.sl("ts0")] = z["c"][1] - level
    return th


def simulate(theta, u, u_pad, ts: float, level: float, ts_free: float, lay: Layout,
             delay: float = 0.0) -> np.ndarray:
    """Simulated temperatures `(T, n)` °C of the baseline zones `theta (n, P)` on inputs `u`
    (`u_pad` before the record), each zone from its own `x0`, with a dead time of `delay`
    samples."""
    uh = held(np.asarray(u, float), np.asarray(u_pad, float), delay)
    uh = np.where(uh > U_OFF, uh, 0.0)
    th = np.asarray(theta, float)
    T = uh.shape[0]
    out = np.empty((T, th.shape[0]))
    for i in range(th.shape[0]):
        a = float(np.exp(th[i, lay.sl("log_a")][0]))
        ad = np.exp(-a * ts)
        tsl = level + ts_free * th[i, lay.sl("ts0")][0]
        drive = uh @ np.exp(th[i, lay.sl("log_b")]) + a * tsl
        out[:, i] = (lfilter([0.0, (1.0 - ad) / a], [1.0, -ad], drive)
                     + th[i, lay.sl("x0")][0] * ad ** np.arange(T))
    return out


__all__ = ["fit", "held", "simulate"]
