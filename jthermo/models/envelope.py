"""What a fitted model knows about its recording (`Envelope`): sample time, the range each
output was recorded in, the input limits, the rest level, the residual noise and the inputs'
spread; and what the model can reach from there (`equilibrium_input`, `check_reachable`,
`Envelope.default_setpoint`).

A fitted model is a plant in its own right: its closed-loop scenarios, set points, limits and
sample time come from this record, never from the virtual printer. `Envelope.from_data` makes
one from the estimation data at fit time; `Envelope.from_model` is the fallback for a model
that carries none (a file written before envelopes, a model built by hand).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .._checks import per_output
from ..errors import ConfigError
from ._base import AbstractModel

#: input limits of a heater: a power fraction in [0, 1]
U_LIMITS = (0.0, 1.0)
#: share of the input span kept free at a set point's equilibrium (control authority)
HEADROOM = 0.02
#: set-point changes are sized so that a first-order closed loop this many times faster than
#: the model's slowest mode follows them without an input leaving its limits
CHANGE_SPEEDUP = 10.0


def _floats(x) -> tuple[float, ...]:
    return tuple(float(v) for v in np.ravel(np.asarray(x, np.float64)))


@dataclasses.dataclass(frozen=True)
class Envelope:
    """A fitted model's recording, per channel (tuples of floats, JSON-ready).

    **Fields:**
    - `ts`: sample time, s.
    - `y_min`, `y_max`: the range each output was recorded in, °C.
    - `u_min`, `u_max`: the input limits, power fraction (the recorded range widened to [0, 1]).
    - `u_mean`, `u_std`: mean and standard deviation of each recorded input (sizes load steps).
    - `rest`: the rest level of each output (its level before any input moved; the
      surroundings), °C.
    - `noise_std`: the outputs' white measurement noise, °C (median absolute deviation of the
      second differences, which the smooth thermal response hardly reaches).
    - `w_mean`: mean of each measured signal, or ().
    - `w_median`: median of each measured signal (the level the operating point and the
      scenarios hold: a fan run half the time at full speed is held at what it mostly did), or
      () (a record written without it: `w_mean` is held).
    - `w_min`, `w_max`: the range each measured signal was recorded in, or () (the `load`
      scenario steps a signal to the end of it farther from its median: `signal_step`).
    """

    ts: float
    y_min: tuple[float, ...]
    y_max: tuple[float, ...]
    u_min: tuple[float, ...]
    u_max: tuple[float, ...]
    u_mean: tuple[float, ...]
    u_std: tuple[float, ...]
    rest: tuple[float, ...]
    noise_std: tuple[float, ...]
    w_mean: tuple[float, ...] = ()
    w_median: tuple[float, ...] = ()
    w_min: tuple[float, ...] = ()
    w_max: tuple[float, ...] = ()

    def __post_init__(self):
        ny, nu = len(self.y_min), len(self.u_min)
        if not (math.isfinite(self.ts) and self.ts > 0):
            raise ConfigError(f"Envelope: sample time must be positive, got {self.ts}")
        if not (len(self.y_max) == len(self.rest) == len(self.noise_std) == ny and ny > 0
                and len(self.u_max) == len(self.u_mean) == len(self.u_std) == nu and nu > 0):
            raise ConfigError("Envelope: per-channel fields of unequal lengths")
        vals = np.concatenate([np.asarray(getattr(self, f.name), np.float64).ravel()
                               for f in dataclasses.fields(self)])
        if not np.all(np.isfinite(vals)):
            raise ConfigError("Envelope: a field is not finite")

    @property
    def n_outputs(self) -> int:
        return len(self.y_min)

    @property
    def n_inputs(self) -> int:
        return len(self.u_min)

    @property
    def span(self) -> np.ndarray:
        """Recorded range of each output, °C (at least 1 °C)."""
        return np.maximum(np.asarray(self.y_max) - np.asarray(self.y_min), 1.0)

    @classmethod
    def from_data(cls, data) -> "Envelope":
        """The envelope of a recording (an `IOData`)."""
        u = np.asarray(data.u, np.float64)
        y = np.asarray(data.y, np.float64)
        w = np.asarray(data.w, np.float64)
        if y.shape[0] < 3:
            raise ConfigError("Envelope.from_data: needs at least three samples")
        lo = np.minimum(u.min(axis=0), U_LIMITS[0])
        hi = np.maximum(u.max(axis=0), U_LIMITS[1])
        # rest: the outputs before the first input change (at least the first sample)
        moved = np.flatnonzero(np.any(np.abs(u - u[0]) > 1e-9, axis=1))
        k = int(moved[0]) if moved.size else y.shape[0]
        rest = y[:max(k, 1)].mean(axis=0) if np.all(u[0] <= lo + 1e-9) else y.min(axis=0)
        d2 = np.diff(y, 2, axis=0)
        mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
        noise = 1.4826 * mad / math.sqrt(6.0)
        return cls(ts=float(data.ts), y_min=_floats(y.min(axis=0)), y_max=_floats(y.max(axis=0)),
                   u_min=_floats(lo), u_max=_floats(hi), u_mean=_floats(u.mean(axis=0)),
                   u_std=_floats(u.std(axis=0)), rest=_floats(rest), noise_std=_floats(noise),
                   w_mean=_floats(w.mean(axis=0)) if w.shape[1] else (),
                   w_median=_floats(np.median(w, axis=0)) if w.shape[1] else (),
                   w_min=_floats(w.min(axis=0)) if w.shape[1] else (),
                   w_max=_floats(w.max(axis=0)) if w.shape[1] else ())

    @classmethod
    def from_model(cls, model: AbstractModel) -> "Envelope":
        """A stand-in for a model that carries no envelope: its own sample time, inputs in
        [0, 1], rest at its equilibrium with the inputs off and the range from rest to its
        equilibrium at half power (no noise known: 0)."""
        ss = model.to_statespace()
        nu, ny = int(ss.B.shape[1]), int(ss.C.shape[0])
        y_off = steady_output(model, np.zeros(nu))
        y_half = steady_output(model, np.full(nu, 0.5))
        return cls(ts=float(ss.ts), y_min=_floats(np.minimum(y_off, y_half)),
                   y_max=_floats(np.maximum(y_off, y_half)), u_min=(0.0,) * nu,
                   u_max=(1.0,) * nu, u_mean=(0.25,) * nu, u_std=(0.1,) * nu,
                   rest=_floats(y_off), noise_std=(0.0,) * ny,
                   w_mean=_floats(ss.w0) if ss.Bw.shape[1] else ())

    def to_dict(self) -> dict:
        """JSON-ready dict (the model file's header keeps it under `meta["envelope"]`)."""
        return {f.name: (getattr(self, f.name) if f.name == "ts" else list(getattr(self, f.name)))
                for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, d: dict) -> "Envelope":
        names = {f.name for f in dataclasses.fields(cls)}
        bad = [k for k in d if k not in names]
        if bad:
            raise ConfigError(f"Envelope: unknown field `{bad[0]}`")
        try:
            return cls(**{k: (float(v) if k == "ts" else _floats(v)) for k, v in d.items()})
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"Envelope: malformed record ({exc})") from None

    def check(self, model: AbstractModel) -> "Envelope":
        """`self`, after checking that it describes `model` (channels and sample time)."""
        ss = model.to_statespace()
        if (int(ss.C.shape[0]), int(ss.B.shape[1])) != (self.n_outputs, self.n_inputs):
            raise ConfigError(f"envelope: recorded {self.n_outputs} outputs / {self.n_inputs} "
                              f"inputs, the model has {ss.C.shape[0]} / {ss.B.shape[1]}")
        if abs(float(ss.ts) - self.ts) > 1e-9 * max(1.0, self.ts):
            raise ConfigError(f"envelope: recorded at Ts {self.ts:g} s, the model runs at "
                              f"{float(ss.ts):g} s")
        lo, hi = min(self.u_min), max(self.u_max)
        if lo < U_LIMITS[0] - 1e-6 or hi > U_LIMITS[1] + 1e-6:
            # the closed loop clips every input to U_LIMITS: a heater recorded in % (0-100) or
            # volts could never be driven past 1 % / 1 V, and no set point would be reached
            raise ConfigError(f"envelope: the recorded inputs span {lo:g} to {hi:g}; a closed "
                              f"loop drives power fractions {U_LIMITS[0]:g} to {U_LIMITS[1]:g} "
                              "(the data contract): rescale the inputs (e.g. % / 100) and refit")
        return self

    def signal_step(self, model: AbstractModel) -> np.ndarray | None:
        """The level each measured signal of `model` steps to in a `load` scenario: of its
        recorded extremes, the one farther from its median (a fan the recording switched on
        steps from what it mostly did to full speed, as the recording shows); None when the
        model takes no signal, the envelope has no recorded range for them, or none moved."""
        nw = int(model.to_statespace().Bw.shape[1])
        if nw == 0 or len(self.w_min) != nw or len(self.w_max) != nw:
            return None
        mid = self.signals(model)
        lo, hi = np.asarray(self.w_min, np.float64), np.asarray(self.w_max, np.float64)
        to = np.where(hi - mid >= mid - lo, hi, lo)
        return to if np.any(np.abs(to - mid) > 0) else None

    def signals(self, model: AbstractModel) -> np.ndarray:
        """The measured signals the operating point and the scenarios hold constant: their
        recorded medians (else means, else the model's own `w0`)."""
        ss = model.to_statespace()
        nw = int(ss.Bw.shape[1])
        if len(self.w_median) == nw:
            return np.asarray(self.w_median, np.float64)
        if len(self.w_mean) == nw:
            return np.asarray(self.w_mean, np.float64)
        return np.asarray(ss.w0, np.float64).reshape(nw)

    def default_setpoint(self, model: AbstractModel) -> np.ndarray:
        """The middle of each output's recorded range, where the model can hold it; else the
        equilibrium at the recorded mean input."""
        mid = 0.5 * (np.asarray(self.y_min) + np.asarray(self.y_max))
        if reach_problem(model, self, mid) is None:
            return mid
        u = np.clip(np.asarray(self.u_mean), np.asarray(self.u_min) + 0.05,
                    np.asarray(self.u_max) - 0.05)
        return steady_output(model, u, self.signals(model))


def steady_gains(model: AbstractModel):
    """`(ss, G, Gw)`: the model's state space and its static gains from the inputs and from the
    measured signals, $G = C (I - A)^{-1} B + D$, $G_w = C (I - A)^{-1} B_w$ (°C per unit)."""
    ss = model.to_statespace()
    A, B, C, D, Bw = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D, ss.Bw))
    inv = np.linalg.solve(np.eye(A.shape[0]) - A, np.concatenate([B, Bw], axis=1))
    nu = B.shape[1]
    return ss, C @ inv[:, :nu] + D, C @ inv[:, nu:]


def steady_output(model: AbstractModel, u, w=None) -> np.ndarray:
    """The model's steady output at constant input `u` (and measured signals `w`, default its
    `w0`), °C."""
    ss, G1, Gw1 = steady_gains(model)
    u0, w0, y0 = (np.asarray(v, np.float64) for v in (ss.u0, ss.w0, ss.y0))
    dw = np.zeros_like(w0) if w is None else np.asarray(w, np.float64) - w0
    return y0 + G1 @ (np.broadcast_to(np.asarray(u, np.float64), u0.shape) - u0) + Gw1 @ dw


def equilibrium_input(model: AbstractModel, setpoint, w=None) -> np.ndarray:
    """The constant input that holds the model's outputs at `setpoint` (°C, scalar or per
    output) with measured signals `w` (default its `w0`): $u^* = u_0 + G(1)^{-1}(r - y_w)$
    (least squares when not square)."""
    ss, G1, _ = steady_gains(model)
    u0 = np.asarray(ss.u0, np.float64)
    r = np.broadcast_to(np.asarray(setpoint, np.float64), (G1.shape[0],))
    return u0 + np.linalg.lstsq(G1, r - steady_output(model, u0, w), rcond=None)[0]


def change_scale(model: AbstractModel, env: Envelope, setpoint, delta,
                 speedup: float = CHANGE_SPEEDUP) -> float:
    """Largest $s \\in [0, 1]$ such that the set-point changes $r \\to r + s\\delta \\to r - s\\delta$
    are followed without an input leaving its limits by a first-order closed loop `speedup`
    ($K$) times faster than the open loop.

    On a first-order plant such a loop's input jumps at a change from $u_a$ to
    $u_a + K (u_b - u_a)$ ($u(0^+) = u_a + (\\tau/\\tau_{cl})(u_b - u_a)$, $u_a$, $u_b$ the
    equilibrium inputs before and after); with $g = G(1)^{-1}\\delta$ the two jumps are
    $u^* + sKg$ (up) and $u^* + s(1 - 2K)g$ (down), each kept within [`u_min`, `u_max`].
    The limits then leave room for such a loop; what the plant's own lag still costs any
    controller is `tune.own.tracking_floor`'s (`experiments/own_plant_limits.py`)."""
    _, G1, _ = steady_gains(model)
    u_star = equilibrium_input(model, setpoint, env.signals(model))
    g = np.linalg.lstsq(G1, np.asarray(delta, np.float64) * np.ones(G1.shape[0]), rcond=None)[0]
    lo, hi = np.asarray(env.u_min), np.asarray(env.u_max)
    s = 1.0
    for c in (speedup * g, (1.0 - 2.0 * speedup) * g):
        up, down = c > 1e-12, c < -1e-12
        s = min(s, *((hi - u_star)[up] / c[up]), *((u_star - lo)[down] / -c[down]))
    return float(max(s, 0.0))


def reach_problem(model: AbstractModel, env: Envelope, setpoint) -> str | None:
    """None when the model can hold `setpoint` within the input limits (keeping `HEADROOM`);
    else one line saying what the heaters can reach."""
    w = env.signals(model)
    r = np.broadcast_to(np.asarray(setpoint, np.float64), (env.n_outputs,))
    if not np.all(np.isfinite(r)):
        return f"set point {_fmt(r)} °C is not a number"
    u = equilibrium_input(model, r, w)
    lo, hi = np.asarray(env.u_min), np.asarray(env.u_max)
    room = HEADROOM * (hi - lo)
    if np.all(np.isfinite(u)) and np.all(u >= lo + room) and np.all(u <= hi - room):
        y = steady_output(model, u, w)
        if np.allclose(y, r, atol=1e-6 * (1 + np.abs(r).max())):
            return None
    y_lo, y_hi = steady_output(model, lo, w), steady_output(model, hi, w)
    return (f"set point {_fmt(r)} °C is beyond reach: it needs inputs {_fmt(u, 3)} (limits "
            f"{_fmt(lo, 2)} to {_fmt(hi, 2)}); the heaters hold the outputs between "
            f"{_fmt(np.minimum(y_lo, y_hi))} and {_fmt(np.maximum(y_lo, y_hi))} °C")


def check_reachable(model: AbstractModel, env: Envelope, setpoint) -> np.ndarray:
    """`setpoint` broadcast per output, after checking the model can hold it
    (`ConfigError` with `reach_problem`'s line otherwise)."""
    msg = reach_problem(model, env, per_output("scenario", "setpoint", setpoint, env.n_outputs))
    if msg is not None:
        raise ConfigError(msg)
    return np.broadcast_to(np.asarray(setpoint, np.float64), (env.n_outputs,)).copy()


def _fmt(x, digits: int = 1) -> str:
    v = np.ravel(np.asarray(x, np.float64))
    s = [f"{a:.{digits}f}" for a in v]
    return s[0] if len(set(s)) == 1 else "[" + ", ".join(s) + "]"


__all__ = ["CHANGE_SPEEDUP", "HEADROOM", "U_LIMITS", "Envelope", "change_scale",
           "check_reachable", "equilibrium_input",
           "reach_problem", "steady_gains", "steady_output"]
