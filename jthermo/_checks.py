"""Shape checks at the public entry points (`design`, `make_scenario` / `check_reachable`,
`closedloop.simulate` / `rollouts`, `tune`): a value of the wrong size is a `ConfigError` with
one line that says what was given and what was expected, never a broadcasting error from
NumPy or JAX several frames down.

Only shapes are read (`np.shape`, `jax.eval_shape`), so the checks also run on traced values
under `jit`, `vmap` and `grad` and cost one abstract trace, no computation."""

from __future__ import annotations

import numpy as np

from .errors import ConfigError


def per_output(where: str, name: str, value, n: int):
    """`value` is a scalar or a 1-D sequence of `n` values (one per output); returns it."""
    shape = np.shape(value)
    if len(shape) > 1 or (len(shape) == 1 and shape[0] not in (1, n)):
        raise ConfigError(f"{where}: {name} needs one value or {n} (one per output), "
                          f"got shape {shape}")
    return value


def controller_fits(where: str, controller, y, r, schedule, n_inputs: int) -> None:
    """The controller accepts measurements and set points shaped like `y`, `r` and returns
    `n_inputs` heater commands: `controller.init(y, r)` then `step_schedule` traced
    abstractly (`equinox.filter_eval_shape`); a shape error inside becomes one line."""
    import equinox as eqx

    def first_input(c, y, r, s):
        return c.step_schedule(c.init(y, r), y, r, s)[0]

    n_out = int(np.shape(y)[-1]) if np.ndim(y) else 1
    try:
        u = eqx.filter_eval_shape(first_input, controller, y, r, schedule)
    except (TypeError, ValueError, IndexError) as exc:
        first = " ".join(str(exc).split())[:160]
        raise ConfigError(f"{where}: the controller {type(controller).__name__} does not fit a "
                          f"plant with {n_out} outputs and {n_inputs} inputs ({first})") from None
    if tuple(u.shape) != (n_inputs,):
        raise ConfigError(f"{where}: the controller {type(controller).__name__} returns "
                          f"{tuple(u.shape)} inputs, the plant takes {n_inputs}")


__all__ = ["controller_fits", "per_output"]
