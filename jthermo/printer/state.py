"""The virtual printer's state and the exogenous signals it takes (see `jthermo.printer`)."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float


class PrinterState(eqx.Module):
    """State of the virtual printer.

    - `z`: the linear states: zone temperatures (°C), then the chamber (°C, heat accumulation),
      lamp powers (power fraction, heater lag), area temperatures (°C, areas 1–3), as present.
    - `buffer`: the last `delay` inputs, oldest first (input delay), `(delay, nu)`.
    - `since`: seconds since the last recoat started.
    """

    z: Float[Array, " nz"]
    buffer: Float[Array, "delay nu"]
    since: Float[Array, ""]


class PrinterDisturbance(eqx.Module):
    """Exogenous signals at one sample (or `(T, ...)` for a run).

    - `recoat`: 1.0 at the sample a recoat starts, else 0.
    - `laser`: absorbed laser power per zone, W.
    - `ambient`: surroundings temperature, °C.
    """

    recoat: Float[Array, ""]
    laser: Float[Array, " zones"]
    ambient: Float[Array, ""]
