"""The printer's effects: default parameters, and the checks that turn a user's effect
selection into complete, valid parameter sets (see `make_printer`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..errors import ConfigError
from .geometry import ZONE_AREA

#: default parameters of every effect (units in the names)
EFFECTS: dict[str, dict[str, Any]] = {
    "lateral_conduction": {"conductance_W_K": None},          # None: from powder conductivity
    "radiative_loss": {"emissivity": None, "area_m2": ZONE_AREA},
    "heat_accumulation": {"share": 0.5, "time_constant_s": 1500.0, "loss_ratio": 1.0},
    "heater_lag": {"time_constant_s": 10.0},
    "input_delay": {"delay_s": 3},
    "input_nonlinearity": {"exponent": 1.5},
    "recoat_cooling": {"period_s": 60.0, "drop_C": 3.0, "duration_s": 8.0, "temperature_C": None,
                       "phase_s": 20.0},
    "laser_exposure": {"power_W": 8.0, "exposure_s": 15.0, "fraction": 0.5, "start_s": 10.0,
                       "period_s": 60.0},
    "ambient_variation": {"amplitude_C": 1.5, "period_s": 1800.0, "walk_C": 0.03,
                          "measured": False},
    "sensor_noise": {"white_std_C": 0.05, "coloured_std_C": 0.1, "pole": 0.9},
    "sensor_offset": {"std_C": 0.5, "offsets_C": None},
}

#: parameters that fix shapes or schedules: kept as Python values (static), not array leaves
STATIC_PARAMS = {("input_delay", "delay_s"), ("ambient_variation", "measured"),
                 ("recoat_cooling", "period_s"), ("recoat_cooling", "duration_s"),
                 ("recoat_cooling", "phase_s"), ("laser_exposure", "exposure_s"),
                 ("laser_exposure", "fraction"), ("laser_exposure", "start_s"),
                 ("laser_exposure", "period_s"), ("ambient_variation", "period_s")}


def normalise_effects(effects) -> dict[str, dict[str, Any]]:
    """`{name: params}` with every parameter filled from `EFFECTS`, from effect names, a
    `{name: {param: value}}` mapping or `{name: True/False}`; unknown names raise."""
    if effects is None:
        return {}
    if isinstance(effects, str):
        effects = [effects]
    if isinstance(effects, Mapping):
        items = list(effects.items())
    else:
        items = [(e, True) for e in effects]
    out = {}
    for name, params in items:
        if name not in EFFECTS:
            raise ConfigError(f"make_printer: unknown effect `{name}` (known: {', '.join(EFFECTS)})")
        if params is False or params is None:
            continue
        if params is True:
            params = {}
        if not isinstance(params, Mapping):
            raise ConfigError(f"make_printer: parameters of `{name}` must be a dict or True")
        for k in params:
            if k not in EFFECTS[name]:
                raise ConfigError(f"make_printer: effect `{name}` has no parameter `{k}` "
                                  f"(known: {', '.join(EFFECTS[name])})")
        out[name] = {**EFFECTS[name], **dict(params)}
    return out


def check_effect_values(leaves, static):
    """Raise `ConfigError` for effect parameters out of range (array leaves and the static
    `(name, param, value)` schedule parameters)."""
    def pos(name, key):
        if name in leaves and key in leaves[name] and not float(leaves[name][key]) > 0:
            raise ConfigError(f"make_printer: `{name}.{key}` must be > 0")
    pos("heater_lag", "time_constant_s")
    pos("heat_accumulation", "time_constant_s")
    pos("input_nonlinearity", "exponent")
    pos("radiative_loss", "area_m2")
    if "heat_accumulation" in leaves and not 0.0 < float(leaves["heat_accumulation"]["share"]) <= 1.0:
        raise ConfigError("make_printer: `heat_accumulation.share` must be in (0, 1]")
    if "sensor_noise" in leaves and not 0.0 <= float(leaves["sensor_noise"]["pole"]) < 1.0:
        raise ConfigError("make_printer: `sensor_noise.pole` must be in [0, 1)")
    for name, key, v in static:
        if key in ("period_s", "duration_s", "exposure_s") and not float(v) > 0:
            raise ConfigError(f"make_printer: `{name}.{key}` must be > 0")
        if key == "fraction" and not 0.0 <= float(v) <= 1.0:
            raise ConfigError(f"make_printer: `{name}.fraction` must be in [0, 1]")

