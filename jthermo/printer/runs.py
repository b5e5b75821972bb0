"""Runs of the virtual printer: disturbance signals for a run, open-loop simulation and
open-loop experiments as `IOData` (`generate`)."""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..data import IOData, from_arrays
from ..errors import ConfigError
from ..identify.padding import bucket
from ..runtime import one_shot
from .geometry import AREA_NAMES
from .plant import Printer, steady_state
from .state import PrinterDisturbance, PrinterState

# ----------------------------------------------------------------------------- disturbances


def _layer_starts(printer: Printer, n_samples: int, phase_s) -> Array:
    """Flags (T,) at the samples where a layer (recoat) starts."""
    if printer.has("recoat_cooling"):
        period = float(printer.param("recoat_cooling", "period_s"))
    else:
        period = float(printer.param("laser_exposure", "period_s"))
    pk = max(1, int(round(period / printer.ts)))
    k = jnp.arange(n_samples)
    ph = jnp.round(jnp.asarray(phase_s) / printer.ts).astype(k.dtype)
    return ((k >= ph) & (((k - ph) % pk) == 0)).astype(printer.capacity.dtype)


def disturbances(printer: Printer, n_samples: int, key, *, recoat: bool | None = None,
                 laser: bool | None = None, ambient: bool | None = None,
                 phase_s=None, drop_scale=1.0) -> PrinterDisturbance:
    """Disturbances `(T, ...)` for a run of `n_samples`, from the printer's effects.

    Recoat flags every `recoat_cooling.period_s` from `phase_s`; laser exposure on a random
    pattern (`fraction` of the zones) per layer, `start_s` after the layer starts, for
    `exposure_s`; surroundings following `ambient_variation` (a sinusoid of random phase plus a
    random walk) or constant. `recoat`/`laser`/`ambient` = False switch a part off; True
    requires the effect. `drop_scale` is unused by the printer physics and kept for builders.
    """
    dt = printer.capacity.dtype
    n, T = printer.zones, int(n_samples)
    k_pat, k_amb, k_walk = jax.random.split(key, 3)
    recoat = printer.has("recoat_cooling") if recoat is None else recoat
    laser = printer.has("laser_exposure") if laser is None else laser
    ambient = printer.has("ambient_variation") if ambient is None else ambient
    for flag, name in ((recoat, "recoat_cooling"), (laser, "laser_exposure"),
                       (ambient, "ambient_variation")):
        if flag and not printer.has(name):
            raise ConfigError(f"this scenario needs a printer with the `{name}` effect "
                              f"(make_printer(effects=[..., '{name}']))")
    if phase_s is None:
        phase_s = printer.param("recoat_cooling", "phase_s") if printer.has("recoat_cooling") else 0.0
    starts = _layer_starts(printer, T, phase_s)
    flags = starts if recoat else jnp.zeros(T, dt)
    q = jnp.zeros((T, n), dt)
    if laser:
        p = printer.effects["laser_exposure"]
        layer = jnp.cumsum(starts).astype(jnp.int32) - 1          # -1 before the first layer
        t_in = jnp.arange(T) - jnp.asarray(
            jax.lax.cummax(jnp.where(starts > 0, jnp.arange(T), -10 ** 9)), jnp.int32)
        t0 = int(round(float(printer.param("laser_exposure", "start_s")) / printer.ts))
        te = int(round(float(printer.param("laser_exposure", "exposure_s")) / printer.ts))
        on = (layer >= 0) & (t_in >= t0) & (t_in < t0 + te)
        frac = float(printer.param("laser_exposure", "fraction"))
        n_layers = int(T // max(1, int(round(float(
            printer.param("recoat_cooling" if printer.has("recoat_cooling") else "laser_exposure",
                          "period_s")) / printer.ts)))) + 2
        pattern = jax.random.bernoulli(k_pat, frac, (n_layers, n)).astype(dt)
        q = jnp.where(on[:, None], pattern[jnp.clip(layer, 0, n_layers - 1)], 0.0) * p["power_W"]
    amb = jnp.full((T,), printer.surroundings, dt)
    if ambient:
        p = printer.effects["ambient_variation"]
        period = float(printer.param("ambient_variation", "period_s"))
        phi = jax.random.uniform(k_amb, (), dt, 0.0, 2 * jnp.pi)
        t = printer.ts * jnp.arange(T, dtype=dt)
        walk = jnp.cumsum(jax.random.normal(k_walk, (T,), dt)) * p["walk_C"] * math.sqrt(printer.ts)
        amb = amb + p["amplitude_C"] * jnp.sin(2 * jnp.pi * t / period + phi) + walk
    return PrinterDisturbance(recoat=flags, laser=q, ambient=amb)


# ----------------------------------------------------------------------------- open loop


@eqx.filter_jit
def simulate_open_loop(printer: Printer, u: Float[Array, "T nu"],
                       d: PrinterDisturbance | None = None, x0: PrinterState | None = None):
    """Open-loop run: `(y, temperatures)`, each `(T, ny)`, noise-free; `y[k] = g(x_k)`."""
    u = jnp.asarray(u, printer.capacity.dtype)
    T = u.shape[0]
    if d is None:
        base = printer.default_disturbance()
        d = jax.tree.map(lambda a: jnp.broadcast_to(a, (T,) + a.shape), base)
    x0 = printer.initial_state() if x0 is None else x0
    plant = printer.discretise()

    def body(x, inp):
        uk, dk = inp
        return plant.step(x, uk, dk), (plant.output(x), plant.temperatures(x))

    _, (y, temps) = jax.lax.scan(body, x0, (u, d))
    return y, temps


def _prbs(seed: int, n_samples: int, n_channels: int, levels, hold=(3, 15)) -> np.ndarray:
    try:
        from ..inputs import prbs as _ext
        out = np.asarray(_ext(seed, n_samples, n_channels, levels=tuple(levels), hold=tuple(hold)))
        if out.shape == (n_samples, n_channels):
            return out
    except (ImportError, AttributeError, TypeError):
        pass
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 11]))
    lo, hi = levels
    u = np.empty((n_samples, n_channels))
    for j in range(n_channels):
        level, t = int(rng.integers(0, 2)), 0
        while t < n_samples:
            h = int(rng.integers(hold[0], hold[1] + 1))
            u[t:t + h, j] = hi if level else lo
            t += h
            level = 1 - level
    return u


def _generate_fn(printer, u, key, u_mean, noise_std, steady: bool):
    T = u.shape[0]
    k_d, k_v = jax.random.split(key)
    d = disturbances(printer, T, k_d)
    x0 = steady_state(printer, u_mean) if steady else printer.ambient_state()
    y, _ = simulate_open_loop(printer, u, d, x0)
    return y + printer.sample_noise(k_v, T, noise_std), d


@functools.cache
def _generate_core():
    """`_generate_fn` compiled with `runtime.one_shot()` options (-O0; probed on first use, not
    at import): an experiment is simulated once per record shape, so a compile in less CPU
    time is worth a slower run (the same outputs to rounding). `generate` runs it on lengths
    from `identify.padding.bucket`'s small set."""
    return eqx.filter_jit(_generate_fn, compiler_options=one_shot())


def experiment_input(experiment: str, seed: int, n_samples: int, n_inputs: int,
                     levels) -> np.ndarray:
    """The input `(T, nu)` of an open-loop experiment (see `generate`). A PRBS is drawn for
    the padded length `bucket(T)` and cut to `T`: its first `T` samples are those drawn for
    `T` itself (every draw is indexed by its sample; tested), and one program draws every
    length of a bucket."""
    T, (lo, hi) = int(n_samples), levels
    if experiment == "prbs":
        L = bucket(T) if jax.config.jax_threefry_partitionable else T
        return np.array(_prbs(seed, L, n_inputs, (lo, hi))[:T])
    if experiment == "step":
        u = np.full((T, n_inputs), lo)
        u[T // 4:] = hi
        return u
    return np.full((T, n_inputs), 0.5 * (lo + hi))


def _generate_padded(printer: Printer, u: np.ndarray, key, u_mean, noise_std, steady: bool):
    """`_generate_fn` on `u (T, nu)` padded to `bucket(T)` samples (its last sample repeated),
    the outputs `(T, ny)` and disturbances cut back to `T` as NumPy arrays. The simulation,
    the disturbances and the noise are causal and their random draws are indexed by sample
    (Threefry in its partitionable form, JAX's default; without it nothing is padded), so the first `T` samples are those of
    the unpadded run to rounding (tested); a process generating records of many lengths
    compiles one simulation per bucket, not per length."""
    T = u.shape[0]
    L = bucket(T) if jax.config.jax_threefry_partitionable else T
    u_pad = np.pad(np.asarray(u, float), ((0, L - T), (0, 0)), mode="edge")
    y, d = _generate_core()(printer, jnp.asarray(u_pad, printer.capacity.dtype), key,
                            u_mean, noise_std, steady)
    return np.asarray(y)[:T], jax.tree.map(lambda a: np.asarray(a)[:T], d)


def input_names(printer: Printer) -> tuple[str, ...]:
    names = tuple(str(i + 1) for i in range(printer.zones))
    return names + (AREA_NAMES if printer.has_areas else ())


def generate(printer: Printer, experiment: str = "prbs", duration: float = 3600.0, *,
             seed: int = 0, levels=(0.3, 0.7), start: str = "steady",
             noise_std: float = 0.05) -> IOData:
    """Open-loop experiment on the printer, as validated `IOData` (absolute °C, u in [0, 1]).

    **Arguments:**
    - `experiment`: `"prbs"` (band-limited PRBS per channel between `levels`, holds of 3–15 s),
      `"step"` (all channels from `levels[0]` to `levels[1]` at a quarter of the run) or
      `"constant"` (the mean of `levels`).
    - `start`: `"steady"` (equilibrium at the mean input) or `"ambient"` (cold start).
    - `noise_std`: white measurement noise (°C), added to the `sensor_noise` effect if on.

    **Returns:** `IOData` with inputs `u_1..u_N` (+ `u_wall, u_plate, u_container`), outputs
    `y_1..y_N` (+ areas), `w_ambient` (the surroundings; the nominal constant unless
    `ambient_variation` has `measured=True`) and, with recoat cooling, `w_recoat` (1.0 at the
    sample a recoat starts). Same seed, same data.
    """
    if experiment not in ("prbs", "step", "constant"):
        raise ConfigError(f"generate: unknown experiment `{experiment}` (prbs, step, constant)")
    if start not in ("steady", "ambient"):
        raise ConfigError(f"generate: start must be 'steady' or 'ambient', got {start!r}")
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration >= 10 * printer.ts):
        raise ConfigError(f"generate: duration must be at least {10 * printer.ts:g} s, got {duration!r}")
    lo, hi = (float(levels[0]), float(levels[1]))
    if not (0.0 <= lo <= 1.0 and 0.0 <= hi <= 1.0):
        raise ConfigError(f"generate: levels must lie in [0, 1], got {levels!r}")
    if not (math.isfinite(noise_std) and noise_std >= 0):
        raise ConfigError(f"generate: noise_std must be >= 0, got {noise_std!r}")
    T = int(round(duration / printer.ts))
    u = experiment_input(experiment, seed, T, printer.n_inputs, (lo, hi))
    key = jax.random.key(int(seed))
    y, d = _generate_padded(printer, u, key, 0.5 * (lo + hi), noise_std, start == "steady")
    measured = printer.has("ambient_variation") and bool(printer.param("ambient_variation", "measured"))
    amb = np.asarray(d.ambient) if measured else np.full(T, float(printer.surroundings))
    w = [amb]
    wnames = ["ambient"]
    if printer.has("recoat_cooling"):
        w.append(np.asarray(d.recoat))
        wnames.append("recoat")
    names = input_names(printer)
    notes = (f"virtual printer: {printer.zones} zones, powder {printer.powder}, effects "
             f"{', '.join(printer.enabled) or 'none'}, experiment {experiment}, seed {seed}",)
    return from_arrays(u, y, printer.ts, np.stack(w, axis=1), input_names=names,
                       output_names=names, signal_names=tuple(wnames), notes=notes)
