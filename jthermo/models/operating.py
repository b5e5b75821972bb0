"""The one operating point of a fitted plant: its default set point and the levels its measured
disturbances are held at.

Every command that runs a fitted plant in closed loop (`tune`, `simulate` whatever the
controller's source, the designs they make) and the Python API (`tune.tune_own_plant`) take it
from `operating_point`, so the same plant gets the same set point everywhere unless one is
given. It is decided by the plant and the recording it was fitted to (`Envelope`):

- measured signals $w$ (a fan, the surroundings): their recorded median (`Envelope.signals`);
  the controller never drives them;
- set point: the middle of each output's recorded range where the plant can hold it within its
  input limits, else the plant's steady output at the recorded mean input
  (`Envelope.default_setpoint`); a given set point is checked against what the heaters reach.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .envelope import Envelope, check_reachable


@dataclasses.dataclass(frozen=True)
class OperatingPoint:
    """`setpoint` per output (°C), `signals` per measured signal, `given`: the set point came
    from the caller (`--setpoint`), not the plant's default."""

    setpoint: tuple[float, ...]
    signals: tuple[float, ...]
    given: bool = False

    @property
    def r(self) -> np.ndarray:
        """The set point as an array, °C."""
        return np.asarray(self.setpoint, np.float64)

    def to_dict(self) -> dict:
        return {"setpoint": list(self.setpoint), "signals": list(self.signals),
                "source": "given" if self.given else "plant default"}

    def line(self) -> str:
        """One line for the terminal."""
        sp = ", ".join(f"{v:.1f}" for v in self.setpoint)
        w = (f"; measured signals held at {', '.join(f'{v:.3g}' for v in self.signals)} "
             "(recorded median)" if self.signals else "")
        return (f"operating point: set point [{sp}] °C "
                f"({'given' if self.given else 'the plant default'}){w}")


def operating_point(plant, envelope: Envelope | None = None, setpoint=None) -> OperatingPoint:
    """The operating point of `plant` (module docstring); `envelope` its recording (default:
    `Envelope.from_model`), `setpoint` a given set point (scalar or per output), checked."""
    env = (Envelope.from_model(plant) if envelope is None else envelope).check(plant)
    r = env.default_setpoint(plant) if setpoint is None else setpoint
    r = check_reachable(plant, env, r)
    w = env.signals(plant)
    return OperatingPoint(setpoint=tuple(float(v) for v in np.ravel(r)),
                          signals=tuple(float(v) for v in np.ravel(w)), given=setpoint is not None)


__all__ = ["OperatingPoint", "operating_point"]
