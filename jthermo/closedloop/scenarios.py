"""Closed-loop scenarios: what goes into a run (`Scenario`: set points, disturbances, noise,
start) and what comes out (`Trajectory`), and the thesis' test scenarios built on the virtual
printer or, through a reference printer, on a fitted model (`make_scenario`)."""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ConfigError
from ..families import MODEL_SCENARIO_KINDS as MODEL_KINDS
from ..families import SCENARIO_KINDS as KINDS
from ..models._base import AbstractModel
from ..models.envelope import (
    Envelope,
    change_scale,
    check_reachable,
    equilibrium_input,
    steady_output,
)
from ..printer import (
    Printer,
    PrinterDisturbance,
    disturbances,
    grid_edges,
    simulate_open_loop,
)
from ..runtime import one_shot

#: default scenario lengths, s
DEFAULT_DURATION = {"tracking": 900.0, "powder": 1200.0, "print": 1200.0, "preheat": 1800.0,
                    "ensemble": 1200.0}
#: the printer `run` uses by default: every effect a real bed shows in closed loop
REALISTIC_EFFECTS = ("lateral_conduction", "radiative_loss", "heat_accumulation", "heater_lag",
                     "recoat_cooling", "laser_exposure", "ambient_variation", "sensor_noise")
STEP_C = 4.0          # the thesis' reference step, °C on all channels
STEP_SHARE = 0.2      # a fitted model's ensemble spread: this share of each output's recorded range
CHANGE_SHARE = 0.1    # its tracking set-point changes: ± this share of the recorded range
CHANGE_ROOM = 0.8     # ... and at most this share of the way to what the input limits can hold
LOAD_SHARE = 0.25     # its load step: this share of each input's recorded std (input-referred)
WINDOW_C = 1.0        # half-width of the print window used by the metrics, °C
PREVIEW_S = 15.0      # how far ahead the build job announces its events to the controller, s
JITTER_S = 2.0        # timing error of the announced events, ± s (uniform, per rollout)
WRONG_P = 0.1         # chance that a zone's announced exposure is wrong, per layer
#: the printer scenarios `make_scenario(..., shared=True)` builds with one compiled program:
#: kind -> (set-point step on, recoat on, laser on), traced flags on the full disturbances
SHARED_KINDS = {"tracking": (1.0, 0.0, 0.0), "powder": (0.0, 1.0, 0.0), "print": (0.0, 1.0, 1.0)}


class ModelDisturbance(eqx.Module):
    """Exogenous signals for a fitted-model plant: measured signals `w` `(T, nw)` and an
    additive output disturbance `dy` `(T, ny)` in °C."""

    w: Float[Array, "T nw"]
    dy: Float[Array, "T ny"]


class Scenario(eqx.Module):
    """One closed-loop test (or a batch, with a leading rollout axis on every array).

    - `r`: set points `(T, ny)`, °C.
    - `d`: plant disturbances `(T, ...)`: `PrinterDisturbance` or `ModelDisturbance`.
    - `v`: measurement noise `(T, ny)`, °C.
    - `y0`: initial temperatures `(ny,)`, °C (steady state there, or a cold start for
      `preheat`).
    - `s`: the build job's event schedule as the controller is told it `(T, 1 + zones)`, or
      None: row k is `[recoat, exposure of zone 1..N]` announced `PREVIEW_S` ahead, with the
      timing jitter and the wrong entries of `event_schedule`.
    """

    r: Float[Array, "T ny"]
    d: Any
    v: Float[Array, "T ny"]
    y0: Float[Array, " ny"]
    s: Float[Array, "T ns"] | None = None
    kind: str = eqx.field(static=True, default="custom")
    window: float = eqx.field(static=True, default=WINDOW_C)
    edges: tuple = eqx.field(static=True, default=())
    ts: float = eqx.field(static=True, default=1.0)
    cold_start: bool = eqx.field(static=True, default=False)

    @property
    def n_samples(self) -> int:
        return int(self.r.shape[-2])


class Trajectory(eqx.Module):
    """A closed-loop run: measured `y`, applied `u` (after saturation), set points `r` and the
    true `temperature` at the sensor positions, each `(T, n)`."""

    y: Float[Array, "T ny"]
    u: Float[Array, "T nu"]
    r: Float[Array, "T ny"]
    temperature: Float[Array, "T ny"]

# ----------------------------------------------------------------------------- scenarios


def event_schedule(printer: Printer, d: PrinterDisturbance, key, *, preview_s: float = PREVIEW_S,
                   jitter_s: float = JITTER_S, wrong_p: float = WRONG_P) -> Float[Array, "T ns"]:
    """The event schedule a controller is told, from the events that happen (`d`).

    Row k is `[recoat, exposure 1..N]` of sample $k + P + \\delta$: the recoat flag and, per
    zone, 1 while the laser exposes it; $P$ = `preview_s` / Ts (the job announces its events
    ahead), $\\delta$ uniform in ±`jitter_s` / Ts per rollout (the announced timing is off), and
    each zone's exposure flipped with probability `wrong_p` per layer period (the announced
    map is wrong; only while the laser runs at all). Zero beyond the run. Traceable in `key`.
    """
    dt = d.laser.dtype
    T, n = d.laser.shape
    k_j, k_w = jax.random.split(key)
    J = int(round(jitter_s / printer.ts))
    shift = int(round(preview_s / printer.ts)) + jax.random.randint(k_j, (), -J, J + 1)
    on = (d.laser > 0).astype(dt)
    if wrong_p > 0 and printer.has("laser_exposure"):
        period = max(1, int(round(float(printer.param("laser_exposure", "period_s")) / printer.ts)))
        flips = jax.random.bernoulli(k_w, wrong_p, (T // period + 1, n)).astype(dt)
        running = jnp.max(on, axis=1, keepdims=True)
        on = jnp.abs(on - running * flips[jnp.arange(T) // period])
    ev = jnp.concatenate([d.recoat[:, None].astype(dt), on], axis=1)
    idx = jnp.arange(T) + shift
    return jnp.where(((idx >= 0) & (idx < T))[:, None], ev[jnp.clip(idx, 0, T - 1)], 0.0)



def unlabelled(x):
    """`x` without its label: a `Printer`'s powder name (read by no simulation) or a
    `Scenario`'s kind (read by no scenario builder, nor by the lean loop of `tune.terms`), so
    that printers of other powders, and scenarios of every kind on the lean loop, share one
    compiled program (`make_scenario`, `tune.group_batch`)."""
    if isinstance(x, Printer):
        return dataclasses.replace(x, powder="")
    if isinstance(x, Scenario):
        return dataclasses.replace(x, kind="")
    return x


def _as_key(key):
    if isinstance(key, (int, np.integer)):
        return jax.random.key(int(key))
    return key


def _printer_scenario(kind: str, printer: Printer, T: int, key, noise_std: float,
                      step_c: float, flags=None):
    """r, d, v, y0 for one rollout on the printer (traceable in `key`). `kind="shared"`: the
    `SHARED_KINDS` scenario picked by the traced `flags` (step, recoat, laser): every part
    drawn from the same keys as the kind's own branch, then switched off by a factor 0, so
    the values are the same and tracking, powder and print share one program."""
    dt = printer.capacity.dtype
    n, ny = printer.zones, printer.n_outputs
    k_d, k_v, k_r, k_p = jax.random.split(key, 4)
    centre = jnp.full((n,), printer.window_centre, dt)
    extra = printer.area["setpoint"] if printer.has_areas else jnp.zeros((0,), dt)

    def full(bed):
        return jnp.concatenate([bed, extra.astype(dt)])

    if kind == "shared":
        d = disturbances(printer, T, k_d, recoat=True, laser=True)
        d = dataclasses.replace(d, recoat=flags[1] * d.recoat, laser=flags[2] * d.laser)
        off = flags[0] * (step_c / 2)
        y0, r = full(centre - off), full(centre + off)
    elif kind == "tracking":
        d = disturbances(printer, T, k_d, recoat=False, laser=False)
        y0 = full(centre - step_c / 2)
        r = full(centre + step_c / 2)
    elif kind == "powder":
        d = disturbances(printer, T, k_d, recoat=True, laser=False)
        y0 = r = full(centre)
    elif kind == "print":
        d = disturbances(printer, T, k_d, recoat=True, laser=True)
        y0 = r = full(centre)
    elif kind == "preheat":
        d = disturbances(printer, T, k_d, recoat=False, laser=False)
        y0 = jnp.full((ny,), printer.surroundings, dt)
        r = full(centre)
    else:   # ensemble: random start, set point and layer phase, events where the printer has them
        period = float(printer.param("recoat_cooling", "period_s"))
        phase = jax.random.randint(k_p, (), 0, max(1, int(period)))
        d = disturbances(printer, T, k_d, phase_s=phase)
        k1, k2 = jax.random.split(k_r)
        y0 = full(centre + jax.random.uniform(k1, (), dt, -step_c, step_c) / 2)
        r = full(centre + jax.random.uniform(k2, (), dt, -step_c, step_c) / 2)
    v = printer.sample_noise(k_v, T, noise_std)
    return jnp.broadcast_to(r, (T, ny)), d, v, y0


def make_scenario(kind: str, plant, duration: float | None = None, key=0, *,
                  n_rollouts: int | None = None, noise_std: float = 0.05,
                  step_c: float = STEP_C, window: float = WINDOW_C,
                  reference: Printer | None = None, envelope: Envelope | None = None,
                  setpoint=None, shared: bool = False) -> Scenario:
    """Build a thesis test scenario for `plant` (a batch with `n_rollouts`).

    **Arguments:**
    - `kind`: `"tracking"` (+`step_c` °C step on every bed channel from steady state below the
      window centre), `"powder"` (recoat layers at the window centre), `"print"` (recoat plus a
      per-layer laser exposure pattern), `"preheat"` (cold start at the surroundings, set point
      the window centre: start-up), `"ensemble"` (random start and set point within ±step_c/2,
      random layer phase, every disturbance the printer has; different per rollout).
    - `plant`: a `Printer`, or a fitted `AbstractModel`: then its own scenarios
      (`model_scenario`, from its recording's `Envelope`), unless a `reference` printer is
      given to provide the window, the surroundings and the output disturbances.
      `envelope` and `setpoint` go to `model_scenario` (fitted models only).
    - `duration` (s, default `DEFAULT_DURATION[kind]`), `key` (a PRNG key or integer seed),
      `noise_std` (white measurement noise, °C, added to the printer's `sensor_noise`).
    - `shared`: build `tracking`, `powder` and `print` on a printer with recoat and laser with
      one compiled program for the three (`SHARED_KINDS`; the same values): for a study that
      builds all three (`tune`); a single kind compiles less without it.
    """
    if kind not in KINDS:
        raise ConfigError(f"make_scenario: unknown scenario `{kind}` (known: {', '.join(KINDS)})")
    if kind == "load" and (isinstance(plant, Printer) or reference is not None):
        raise ConfigError("make_scenario: `load` is a fitted model's scenario; the virtual "
                          "printer's disturbances are `powder` and `print`")
    if isinstance(plant, AbstractModel) and reference is None:
        # a fitted model is a plant in its own right: its scenarios come from its recording
        return model_scenario(kind, plant, duration, key, n_rollouts=n_rollouts,
                              step_c=None if step_c == STEP_C else step_c, window=window,
                              envelope=envelope, setpoint=setpoint)
    duration = DEFAULT_DURATION.get(kind, 1200.0) if duration is None else duration
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ConfigError(f"make_scenario: duration must be a positive number of seconds, got {duration!r}")
    if n_rollouts is not None and (not isinstance(n_rollouts, (int, np.integer)) or n_rollouts < 1):
        raise ConfigError(f"make_scenario: n_rollouts must be a positive integer, got {n_rollouts!r}")
    key = _as_key(key)
    if isinstance(plant, Printer):
        printer, model = plant, None
    elif isinstance(plant, AbstractModel):
        model = plant
        printer = reference
        if printer.n_outputs != model.n_outputs:
            raise ConfigError(f"make_scenario: the model has {model.n_outputs} outputs, the "
                              f"reference printer {printer.n_outputs}")
    else:
        raise ConfigError(f"make_scenario: unsupported plant {type(plant).__name__}")
    T = int(round(duration / printer.ts))
    if T < 2:
        raise ConfigError(f"make_scenario: duration {duration} s is shorter than two samples")

    keys = key if n_rollouts is None else jax.random.split(key, int(n_rollouts))
    build, flags = kind, None
    if shared and kind in SHARED_KINDS and printer.has("recoat_cooling") \
            and printer.has("laser_exposure"):
        build, flags = "shared", jnp.asarray(SHARED_KINDS[kind], printer.capacity.dtype)
    # one compiled builder per kind for printers of every powder (the name is only a label)
    r, d, v, y0, s = _build_scenario(build, unlabelled(printer), model, T, keys,
                                     float(noise_std), float(step_c), n_rollouts is not None,
                                     flags)
    return Scenario(r=r, d=d, v=v, y0=y0, s=s, kind=kind, window=float(window),
                    edges=grid_edges(printer.zones), ts=printer.ts,
                    cold_start=(kind == "preheat"))


@functools.cache
def _jitted_make_scenario():
    return eqx.filter_jit(make_scenario, compiler_options=one_shot())


def compiled_make_scenario():
    """`make_scenario` (the same arguments) with a printer's scenarios built as one compiled
    program with `runtime.one_shot()` options (non-array arguments static), for scenarios built
    once per process: -O0 compiles the scenario program in a fraction of the default options'
    time (`runtime.ONE_SHOT`), and a program run once does not repay a slower, optimised
    compile. A fitted model's scenarios (which check their envelope in Python) are built by
    `make_scenario`."""
    jitted = _jitted_make_scenario()

    def build(kind, plant, *args, **kw):
        return (jitted if isinstance(plant, Printer) else make_scenario)(kind, plant, *args, **kw)

    return build


@eqx.filter_jit
def _build_scenario(kind, printer, model, T, keys, noise_std, step_c, batched, flags=None):
    def one(k):
        r, d, v, y0 = _printer_scenario(kind, printer, T, k, noise_std, step_c, flags)
        # its own key (folded in): the other signals keep the draws they had without it
        s = event_schedule(printer, d, jax.random.fold_in(k, 16))
        if model is not None:
            d = _model_disturbance(model, printer, d)
        return r, d, v, y0, s

    return jax.vmap(one)(keys) if batched else one(keys)


def _model_disturbance(model: AbstractModel, printer: Printer, d: PrinterDisturbance):
    """Map printer disturbances onto a fitted model: `w` gets the surroundings, and recoat/laser
    become the output disturbance they cause on the reference printer in open loop."""
    ss = model.to_statespace()
    T = d.ambient.shape[0]
    nw = ss.Bw.shape[1]
    w = jnp.broadcast_to(ss.w0, (T, nw))
    if nw:
        w = w.at[:, 0].set(d.ambient)
    u = jnp.broadcast_to(printer.steady_input(), (T, printer.n_inputs))
    x0 = printer.initial_state()
    quiet = PrinterDisturbance(recoat=jnp.zeros_like(d.recoat), laser=jnp.zeros_like(d.laser),
                               ambient=jnp.broadcast_to(printer.surroundings, d.ambient.shape))
    events = PrinterDisturbance(recoat=d.recoat, laser=d.laser, ambient=quiet.ambient)
    y1, _ = simulate_open_loop(printer, u, events, x0)
    y0, _ = simulate_open_loop(printer, u, quiet, x0)
    dy = y1 - y0
    if not nw:   # no measured surroundings: its drift acts at the output as well
        ya, _ = simulate_open_loop(printer, u, PrinterDisturbance(
            recoat=quiet.recoat, laser=quiet.laser, ambient=d.ambient), x0)
        dy = dy + ya - y0
    return ModelDisturbance(w=w, dy=dy)



# ----------------------------------------------------------------------------- a fitted model's own


def model_duration(model: AbstractModel) -> float:
    """A fitted model's natural scenario length, s: five times its slowest time constant,
    between 200 and 5000 samples."""
    A = np.asarray(model.to_statespace().A, np.float64)
    rho = float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0
    ts = float(model.ts)
    tau = -ts / math.log(rho) if 0.0 < rho < 1.0 else 0.0
    return ts * float(np.clip(round(5.0 * tau / ts), 200, 5000))


def model_scenario(kind: str, model: AbstractModel, duration: float | None = None, key=0, *,
                   n_rollouts: int | None = None, envelope: Envelope | None = None,
                   setpoint=None, step_c=None, load=None, window: float = WINDOW_C) -> Scenario:
    """A closed-loop test of a fitted model on its own terms: sample time, set points, input
    limits, load sizes and noise from its recording's `Envelope` (`envelope`, default
    `Envelope.from_model`), never from the virtual printer.

    **Arguments:**
    - `kind`: `"tracking"` (set-point changes around the operating point: settled at the set
      point $r$, it moves to $r + \\delta$ at 10 % of the run and to $r - \\delta$ at 55 %;
      $\\delta$ = `step_c` °C per output, default `CHANGE_SHARE` of the recorded range, at most
      `CHANGE_ROOM` of the way to the output the inputs hold at their limits, scaled down
      (`models.envelope.change_scale`) until a first-order loop `CHANGE_SPEEDUP` times faster
      than the plant follows both changes without an input leaving its limits: the changes
      test the loop, not the heaters' power), `"load"` (at the set point, an input-referred heat
      sink of `load` per input — default `LOAD_SHARE` of the recorded input std, at most half
      the distance to the input limits — switched on at 20–30 % and off at 60–70 % of the
      run; a plant with measured signals whose recording moved them, a fan, instead steps
      those signals as the recording shows, from their median to their recorded extreme
      farther from it, `Envelope.signal_step`, over the same span: the disturbance the plant
      was fitted with, which the controller never drives), `"preheat"` (the start-up step: from the model's equilibrium with the heaters off
      to the set point; power-limited, reported on its own), `"ensemble"` (random set point
      within ±`STEP_SHARE`·range/4, start within `STEP_SHARE`·range below it, and a load of
      random sign; per rollout).
    - `duration`: s, default `model_duration(model)`; `key`: PRNG key or seed.
    - `setpoint`: °C, scalar or per output; default `envelope.default_setpoint`. A set point
      the inputs cannot hold is a `ConfigError` saying what they can reach.
    - `window`: half-width of the metrics' window, °C (at least 3 noise std).

    The plant starts at steady state (`Scenario.y0`); white measurement noise of the
    recording's `noise_std`; the measured signals `w` are held at their recorded medians
    (`Envelope.signals`), stepped only by `load` as above.
    """
    if kind not in MODEL_KINDS:
        raise ConfigError(f"model_scenario: scenario `{kind}` is not one of a fitted model's "
                          f"({', '.join(MODEL_KINDS)}); `powder` and `print` need the virtual "
                          "printer (make_scenario(..., reference=printer))")
    env = (Envelope.from_model(model) if envelope is None else envelope).check(model)
    duration = model_duration(model) if duration is None else duration
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ConfigError(f"model_scenario: duration must be a positive number of seconds, got {duration!r}")
    if n_rollouts is not None and (not isinstance(n_rollouts, (int, np.integer)) or n_rollouts < 1):
        raise ConfigError(f"model_scenario: n_rollouts must be a positive integer, got {n_rollouts!r}")
    T = int(round(duration / env.ts))
    if T < 2:
        raise ConfigError(f"model_scenario: duration {duration} s is shorter than two samples")
    r = check_reachable(model, env, env.default_setpoint(model) if setpoint is None else setpoint)
    w = env.signals(model)
    lo, hi = np.asarray(env.u_min), np.asarray(env.u_max)
    y_off = steady_output(model, lo, w)
    step = STEP_SHARE * env.span
    y_top = steady_output(model, hi, w)
    change = np.minimum(CHANGE_SHARE * env.span, CHANGE_ROOM * np.minimum(y_top - r, r - y_off))
    change = change * change_scale(model, env, r, np.maximum(change, 0.0))
    if step_c is not None:
        step = change = np.broadcast_to(np.abs(np.asarray(step_c, np.float64)), r.shape)
    u_star = equilibrium_input(model, r, w)
    size = LOAD_SHARE * np.asarray(env.u_std) if load is None else np.broadcast_to(
        np.asarray(load, np.float64), u_star.shape)
    size = np.minimum(size, 0.5 * np.minimum(u_star - lo, hi - u_star))
    w_to = env.signal_step(model) if kind == "load" and load is None else None
    dt = jnp.asarray(model.to_statespace().A).dtype
    S = jnp.asarray(model.step_response(T), dt)                      # (T, ny, nu)
    consts = {k: jnp.asarray(v, dt) for k, v in (("r", r), ("step", step), ("y_off", y_off),
                                                 ("change", np.maximum(change, 0.0)),
                                                 ("size", size), ("w", w),
                                                 ("w_to", w if w_to is None else w_to),
                                                 ("noise", env.noise_std))}
    key = _as_key(key)
    keys = key if n_rollouts is None else jax.random.split(key, int(n_rollouts))
    r_, dy, v, y0, wT = _build_model_scenario(kind, S, consts, T, keys, n_rollouts is not None,
                                              w_to is not None)
    return Scenario(r=r_, d=ModelDisturbance(w=wT, dy=dy), v=v, y0=y0, kind=kind,
                    window=max(float(window), 3.0 * float(np.max(env.noise_std))), ts=env.ts)


@eqx.filter_jit
def _build_model_scenario(kind, S, c, T, keys, batched, signal_load=False):
    def shifted(k0):       # the step response delayed to start at sample k0: (T, ny, nu)
        idx = jnp.arange(T) - k0
        return jnp.where((idx >= 0)[:, None, None], S[jnp.clip(idx, 0, T - 1)], 0.0)

    def one(k):
        k_t, k_on, k_off, k_r, k_s, k_v = jax.random.split(k, 6)
        r, zero = c["r"], jnp.zeros_like(c["r"])
        sign = -1.0
        if kind == "tracking":
            y0 = r
            k = jnp.arange(T)[:, None]
            up, down = int(0.1 * T), int(0.55 * T)
            path = r + c["change"] * (jnp.where(k >= up, 1.0, 0.0) - jnp.where(k >= down, 2.0, 0.0))
        elif kind == "preheat":
            y0 = c["y_off"]
        elif kind == "ensemble":
            r = r + c["step"] * jax.random.uniform(k_r, r.shape, r.dtype, -0.25, 0.25)
            y0 = jnp.maximum(r - c["step"] * jax.random.uniform(k_t, r.shape, r.dtype),
                             c["y_off"])
            sign = jnp.where(jax.random.bernoulli(k_s), 1.0, -1.0)
        else:   # load
            y0 = r
        w = jnp.broadcast_to(c["w"], (T, c["w"].shape[0]))
        dy = jnp.broadcast_to(zero, (T, r.shape[0]))
        if kind in ("load", "ensemble"):
            on = jax.random.randint(k_on, (), int(0.2 * T), max(int(0.3 * T), int(0.2 * T) + 1))
            off = jax.random.randint(k_off, (), int(0.6 * T), max(int(0.7 * T), int(0.6 * T) + 1))
            if signal_load:         # the measured signals stepped, the plant's own response
                k = jnp.arange(T)[:, None]
                w = w + jnp.where((k >= on) & (k < off), 1.0, 0.0) * (c["w_to"] - c["w"])
            else:
                dy = (shifted(on) - shifted(off)) @ (sign * c["size"])
        v = c["noise"] * jax.random.normal(k_v, (T, r.shape[0]), r.dtype)
        if kind == "tracking":
            return path, dy, v, y0, w
        return jnp.broadcast_to(r, (T, r.shape[0])), dy, v, y0, w

    return jax.vmap(one)(keys) if batched else one(keys)
