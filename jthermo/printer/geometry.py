"""Geometry and materials of the virtual printer: physical constants, powder presets and the
near-square zone grid (row-major positions, neighbour edges)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

KELVIN = 273.15
SIGMA = 5.670374419e-8          # Stefan–Boltzmann, W/(m² K⁴)
ZONE_AREA = 0.01                # m², one 10 cm × 10 cm zone
HEATED_DEPTH = 0.004            # m, effective depth of powder that follows the surface temperature
NOMINAL_INPUT = 0.5             # power fraction that holds the bed at the window centre
AREA_NAMES = ("wall", "plate", "container")


# ----------------------------------------------------------------------------- powders


@dataclasses.dataclass(frozen=True)
class Powder:
    """Material preset: bulk properties and the print window (°C)."""

    name: str
    density: float              # kg/m³, bulk powder
    heat_capacity: float        # J/(kg K)
    emissivity: float           # -
    conductivity: float         # W/(m K), bulk powder
    window: tuple[float, float]  # °C, target bed window
    fresh_temperature: float    # °C, new powder leaving the container

    @property
    def target(self) -> float:
        return 0.5 * (self.window[0] + self.window[1])


POWDERS: dict[str, Powder] = {
    "PA12": Powder("PA12", 450.0, 2000.0, 0.90, 0.10, (172.0, 176.0), 100.0),
    "PA11": Powder("PA11", 500.0, 2100.0, 0.92, 0.12, (186.0, 190.0), 110.0),
}


# ----------------------------------------------------------------------------- grid


def grid_shape(zones: int) -> tuple[int, int]:
    """(rows, cols) of the near-square grid: rows = floor(sqrt N), cols = ceil(N / rows)."""
    rows = max(1, int(math.floor(math.sqrt(zones))))
    return rows, int(math.ceil(zones / rows))


def grid_positions(zones: int) -> np.ndarray:
    """`(N, 2)` (row, column) positions with unit spacing, row-major."""
    _, cols = grid_shape(zones)
    idx = np.arange(zones)
    return np.stack([idx // cols, idx % cols], axis=1).astype(float)


def grid_edges(zones: int) -> tuple[tuple[int, int], ...]:
    """Pairs (i, j), i < j, of zones that share a grid side."""
    pos = grid_positions(zones)
    out = []
    for i in range(zones):
        for j in range(i + 1, zones):
            if abs(pos[i] - pos[j]).sum() == 1.0:
                out.append((i, j))
    return tuple(out)

