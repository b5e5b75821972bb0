"""Does a controller × plant × scenario loop fit together? One-line `ConfigError`s for the
mistakes a script makes (a scenario built for another plant, a controller designed for another
number of zones) before they surface as attribute or broadcasting errors inside `lax.scan`."""

from __future__ import annotations

import numpy as np

from .._checks import controller_fits
from ..errors import ConfigError
from ..models._base import AbstractModel
from ..printer import DiscretePrinter, Printer
from .scenarios import ModelDisturbance, Scenario


def plant_size(plant) -> tuple[int, int]:
    """(inputs, outputs) of a `Printer`, `DiscretePrinter` or fitted model."""
    if isinstance(plant, DiscretePrinter):
        plant = plant.printer
    if isinstance(plant, (Printer, AbstractModel)):
        return int(plant.n_inputs), int(plant.n_outputs)
    raise ConfigError(f"closed loop: unsupported plant {type(plant).__name__} "
                      "(a Printer or a fitted AbstractModel)")


def _what(is_model: bool) -> str:
    return "a fitted model" if is_model else "the virtual printer"


def check_loop(where: str, plant, controller, scenario: Scenario | None = None) -> None:
    """`scenario` (one run, `(T, ny)`) was built for this kind of plant and its number of
    outputs, and `controller` maps the plant's outputs to its inputs."""
    n_in, n_out = plant_size(plant)
    if scenario is None:
        y = r = np.zeros(n_out)
        s = None
    else:
        is_model = isinstance(plant, AbstractModel)
        if isinstance(scenario.d, ModelDisturbance) != is_model:
            raise ConfigError(f"{where}: the scenario was built for "
                              f"{_what(not is_model)}, the plant is {_what(is_model)} "
                              "(build it with make_scenario(kind, plant))")
        ny = np.shape(scenario.r)[-1]
        if ny != n_out:
            raise ConfigError(f"{where}: the scenario has set points for {ny} outputs, the "
                              f"plant has {n_out}")
        y = r = scenario.r[0]
        s = None if scenario.s is None else scenario.s[0]
    controller_fits(where, controller, y, r, s, n_in)


__all__ = ["check_loop", "plant_size"]
