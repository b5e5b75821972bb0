"""Building a virtual printer: `make_printer` (zones, effects, powder, areas, overrides)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..errors import ConfigError
from .effects import STATIC_PARAMS, check_effect_values, normalise_effects
from .geometry import (
    HEATED_DEPTH,
    NOMINAL_INPUT,
    POWDERS,
    ZONE_AREA,
    grid_positions,
    grid_shape,
)
from .plant import Printer


def _leaf(v, dtype) -> Array:
    """`jnp.asarray(v, dtype)`, NumPy converting host values (no eager conversion program to
    trace, lower and look up in the compilation cache): the same array, bit for bit."""
    if isinstance(v, jax.Array):
        return jnp.asarray(v, dtype)
    return jax.device_put(np.asarray(v, dtype))


def make_printer(zones: int = 4, effects: Mapping[str, Mapping] | Iterable[str] = (), *,
                 powder: str = "PA12", seed: int = 0, areas: bool = False,
                 **overrides) -> Printer:
    """Build a virtual printer.

    **Arguments:**
    - `zones`: number of bed zones N (1–256), on a near-square grid.
    - `effects`: effect names (defaults) or `{name: {param: value}}` (see `EFFECTS`).
    - `powder`: a key of `POWDERS` (`"PA12"`, `"PA11"`): capacity, emissivity, conductivity,
      print window, and the chamber (surroundings) temperature that goes with it.
    - `seed`: zone-to-zone variation of capacity, loss and heater power (±8 %), sensor offsets.
    - `areas`: add areas 1–3 (wall, build plate, container) with heaters and thermocouples.
    - `overrides`: `capacity`, `loss` (W/K), `gain` (N×N, W), `surroundings` (°C),
      `footprint_width` (grid units), `heater_power` (W, total per zone at u = 1),
      `spread` (relative variation), `substeps`, `ts`, `dtype`.
    """
    if not isinstance(zones, (int, np.integer)) or not 1 <= zones <= 256:
        raise ConfigError(f"make_printer: zones must be an integer in 1..256, got {zones!r}")
    if powder not in POWDERS:
        raise ConfigError(f"make_printer: unknown powder `{powder}` (known: {', '.join(POWDERS)})")
    known = {"capacity", "loss", "gain", "surroundings", "footprint_width", "heater_power",
             "spread", "substeps", "ts", "dtype"}
    bad = [k for k in overrides if k not in known]
    if bad:
        raise ConfigError(f"make_printer: unknown option `{bad[0]}` (known: {', '.join(sorted(known))})")
    pw = POWDERS[powder]
    n = int(zones)
    eff = normalise_effects(effects)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), n, 7]))
    spread = float(overrides.get("spread", 0.08))
    jitter = lambda: 1.0 + spread * rng.uniform(-1.0, 1.0, n)
    cap_nominal = pw.density * pw.heat_capacity * ZONE_AREA * HEATED_DEPTH     # J/K (≈36 for PA12)
    loss_nominal = 0.6                                                         # W/K (τ ≈ 60 s)
    rise = 29.0                      # K above the surroundings at the nominal input 0.5
    capacity = np.asarray(overrides.get("capacity", cap_nominal * jitter()), float)
    loss = np.asarray(overrides.get("loss", loss_nominal * jitter()), float)
    power_scale = jitter()
    if "gain" in overrides:
        gain = np.asarray(overrides["gain"], float)
    else:
        width = float(overrides.get("footprint_width", 0.7))
        pos = grid_positions(n)
        d2 = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1)
        foot = np.exp(-d2 / (2 * width ** 2)) * power_scale[None, :]
        total = float(overrides.get("heater_power", loss_nominal * rise / NOMINAL_INPUT))
        gain = foot * total / foot.sum(1).mean()
    surroundings = float(overrides.get("surroundings", pw.target - rise))
    for name, arr, shape in (("capacity", capacity, (n,)), ("loss", loss, (n,)), ("gain", gain, (n, n))):
        if arr.shape != shape:
            raise ConfigError(f"make_printer: `{name}` has shape {arr.shape}, expected {shape}")
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"make_printer: `{name}` must be finite")
    if np.any(capacity <= 0) or np.any(loss <= 0) or np.any(gain < 0):
        raise ConfigError("make_printer: capacity and loss must be > 0 and gain >= 0")
    dtype = overrides.get("dtype", None) or jnp.result_type(float)

    # effect parameters: fill powder-dependent defaults, split static from array leaves
    static = []
    leaves: dict[str, dict[str, Array]] = {}
    for name, params in eff.items():
        params = dict(params)
        if name == "lateral_conduction" and params["conductance_W_K"] is None:
            params["conductance_W_K"] = 1.5 * pw.conductivity          # 0.15 W/K for PA12
        if name == "radiative_loss" and params["emissivity"] is None:
            params["emissivity"] = pw.emissivity
        if name == "recoat_cooling" and params["temperature_C"] is None:
            params["temperature_C"] = pw.fresh_temperature
        if name == "sensor_offset":
            off = params.pop("offsets_C")
            std = params.pop("std_C")
            if off is None:
                off = std * rng.standard_normal(n)
            off = np.asarray(off, float)
            if off.shape != (n,):
                raise ConfigError(f"make_printer: `offsets_C` must have {n} values")
            params = {"offsets_C": off}
        leaves[name] = {}
        for k, v in params.items():
            if (name, k) in STATIC_PARAMS:
                static.append((name, k, v))
            else:
                leaves[name][k] = _leaf(v, dtype)
    delay = 0
    if "input_delay" in eff:
        ds = eff["input_delay"]["delay_s"]
        ts = float(overrides.get("ts", 1.0))
        delay = int(round(float(ds) / ts))
        if delay < 0 or abs(delay * ts - float(ds)) > 1e-9:
            raise ConfigError(f"make_printer: input_delay delay_s must be a whole number of samples, got {ds}")
    check_effect_values(leaves, static)
    area = {}
    if areas:
        edge = np.zeros(n)
        rows, cols = grid_shape(n)
        pos = grid_positions(n)
        edge[(pos[:, 0] == 0) | (pos[:, 0] == rows - 1) | (pos[:, 1] == 0) | (pos[:, 1] == cols - 1)] = 1.0
        area = {
            "capacity": _leaf([2000.0, 3000.0, 1500.0], dtype),   # J/K
            "loss": _leaf([2.0, 3.0, 1.5], dtype),                # W/K to surroundings
            "power": _leaf([60.0, 150.0, 20.0], dtype),           # W at u = 1
            "wall_coupling": _leaf(0.05 * edge, dtype),           # W/K zone <-> wall
            "plate_coupling": _leaf(np.full(n, 0.1), dtype),      # W/K zone <-> plate
            "wall_container": _leaf(0.5, dtype),                  # W/K wall <-> container
            "setpoint": _leaf([surroundings + 10.0, pw.target - 6.0, surroundings + 5.0], dtype),
        }
    substeps = int(overrides.get("substeps", 10))
    return Printer(capacity=_leaf(capacity, dtype), loss=_leaf(loss, dtype),
                   gain=_leaf(gain, dtype), surroundings=_leaf(surroundings, dtype),
                   effects=leaves, area=area, static=tuple(static), zones=n, delay=delay,
                   substeps=substeps, ts=float(overrides.get("ts", 1.0)), powder=powder,
                   window=_leaf(pw.window, dtype), has_areas=bool(areas))

