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


def _state_like(plant, scenario: Scenario):
    """Shapes of the state `initial_state(plant, scenario)` returns (traced abstractly)."""
    import equinox as eqx

    if isinstance(plant, AbstractModel):
        return eqx.filter_eval_shape(lambda m: m.to_statespace().A[0], plant)
    pr = plant.printer if isinstance(plant, DiscretePrinter) else plant
    return eqx.filter_eval_shape(lambda p, y0, a: p.initial_state(y0, ambient=a), pr,
                                 scenario.y0, scenario.d.ambient[0])


def _shapes(tree) -> list:
    import jax

    return [tuple(np.shape(x)) for x in jax.tree.leaves(tree)]


def check_loop(where: str, plant, controller, scenario: Scenario | None = None,
               x0=None) -> None:
    """`scenario` (one run, `(T, ny)`) was built for this kind of plant and its number of
    outputs, `controller` maps the plant's outputs to its inputs, and a given start state
    `x0` has the structure and shapes of the plant's state."""
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
        if x0 is not None:
            import jax

            like = _state_like(plant, scenario)
            if jax.tree.structure(x0) != jax.tree.structure(like) or _shapes(x0) != _shapes(like):
                raise ConfigError(f"{where}: x0 has shapes {_shapes(x0)}, the plant's state "
                                  f"has {_shapes(like)}")
    controller_fits(where, controller, y, r, s, n_in)


__all__ = ["check_loop", "plant_size"]
