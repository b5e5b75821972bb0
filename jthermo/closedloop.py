"""Closed-loop simulation: controller × plant × scenario, one `lax.scan` over time.

```
y_k = g(x_k) + v_k                      (measured, °C; v = measurement noise)
u_k, c_{k+1} = controller.step(c_k, y_k, r_k);   u_k <- clip(u_k, 0, 1)
x_{k+1} = f(x_k, u_k, d_k)              (plant, one sample Ts)
```

Plants are the virtual printer (`jthermo.printer.Printer`, disturbances `PrinterDisturbance`:
recoat flags, laser power per zone, surroundings) or any fitted `AbstractModel`. A fitted
model has no recoat or laser input, so its scenario carries `ModelDisturbance`: the measured
signals `w` it was fitted with (`w[:, 0]` = surroundings temperature) and an additive *output*
disturbance `dy`, the open-loop response of a reference printer to the same recoat/laser events
(superposition: exact for a linear plant). Batches come from `rollouts` (vmap over scenarios and,
with `plant_axis=0`, over a stacked batch of plants). Everything is pure and differentiable with
respect to controller gains and plant parameters.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .control._base import AbstractController
from .errors import ConfigError
from .families import SCENARIO_KINDS as KINDS
from .models._base import AbstractModel
from .printer import (
    DiscretePrinter,
    Printer,
    PrinterDisturbance,
    disturbances,
    grid_edges,
    make_printer,
    simulate_open_loop,
)

#: default scenario lengths, s
DEFAULT_DURATION = {"tracking": 900.0, "powder": 1200.0, "print": 1200.0, "preheat": 1800.0,
                    "ensemble": 1200.0}
#: the printer `run` uses by default: every effect a real bed shows in closed loop
REALISTIC_EFFECTS = ("lateral_conduction", "radiative_loss", "heat_accumulation", "heater_lag",
                     "recoat_cooling", "laser_exposure", "ambient_variation", "sensor_noise")
STEP_C = 4.0          # the thesis' reference step, °C on all channels
WINDOW_C = 1.0        # half-width of the print window used by the metrics, °C


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
    """

    r: Float[Array, "T ny"]
    d: Any
    v: Float[Array, "T ny"]
    y0: Float[Array, " ny"]
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


# ----------------------------------------------------------------------------- plant adapters


class _PrinterPlant(eqx.Module):
    disc: DiscretePrinter

    def step(self, x, u, d):
        return self.disc.step(x, u, d)

    def measure(self, x, d):
        return self.disc.output(x), self.disc.temperatures(x)


class _ModelPlant(eqx.Module):
    model: AbstractModel

    def step(self, x, u, d):
        w = d.w if d.w.shape[-1] else None
        return self.model.step(x, u, w)

    def measure(self, x, d):
        y = self.model.output(x) + d.dy
        return y, y


class _LinearPlant(eqx.Module):
    """A linear model's state space, built once outside the scan: one matrix product per step."""

    M: Array          # [A  B  Bw]
    C: Array
    u0: Array
    w0: Array
    y0: Array

    def step(self, x, u, d):
        parts = [x, u - self.u0]
        if self.w0.shape[0]:
            parts.append(d.w - self.w0)
        return self.M @ jnp.concatenate(parts)

    def measure(self, x, d):
        y = self.y0 + self.C @ x + d.dy
        return y, y


def _prepare(plant):
    if isinstance(plant, Printer):
        return _PrinterPlant(plant.discretise())
    if isinstance(plant, DiscretePrinter):
        return _PrinterPlant(plant)
    if isinstance(plant, AbstractModel):
        if type(plant).step is AbstractModel.step and type(plant).output is AbstractModel.output:
            # the default plant interface goes through the state space: build it once
            ss = plant.to_statespace()
            return _LinearPlant(M=jnp.concatenate([ss.A, ss.B, ss.Bw], axis=1), C=ss.C,
                                u0=ss.u0, w0=ss.w0, y0=ss.y0)
        return _ModelPlant(plant)
    raise ConfigError(f"closed loop: unsupported plant {type(plant).__name__} "
                      "(a Printer or a fitted AbstractModel)")


def _n_outputs(plant) -> int:
    if isinstance(plant, Printer):
        return plant.n_outputs
    return int(plant.n_outputs)


def _model_steady_state(model: AbstractModel, y0, w):
    """Steady state of a linear model with output `y0` given measured signals `w`."""
    ss = model.to_statespace()
    eye = jnp.eye(ss.A.shape[0], dtype=ss.A.dtype)
    M = jnp.linalg.solve(eye - ss.A, jnp.concatenate([ss.B, ss.Bw], axis=1))
    nu = ss.B.shape[1]
    MB, MBw = M[:, :nu], M[:, nu:]
    dw = (w - ss.w0) if ss.Bw.shape[1] else jnp.zeros((0,), ss.A.dtype)
    target = jnp.asarray(y0, ss.A.dtype) - ss.y0 - ss.C @ (MBw @ dw)
    du = jnp.linalg.lstsq(ss.C @ MB, target)[0]
    return MB @ du + MBw @ dw


def initial_state(plant, scenario: Scenario):
    """The plant state a scenario starts from: steady at `scenario.y0`, or everything at the
    surroundings for a cold start (`preheat`)."""
    if isinstance(plant, Printer):
        amb = scenario.d.ambient[0]
        if scenario.cold_start:
            return plant.ambient_state(amb)
        y0 = scenario.y0
        if plant.has("sensor_offset"):
            pass   # y0 are true temperatures: offsets only affect the readings
        return plant.initial_state(y0, ambient=amb)
    if isinstance(plant, AbstractModel):
        return _model_steady_state(plant, scenario.y0, scenario.d.w[0])
    raise ConfigError(f"closed loop: unsupported plant {type(plant).__name__}")


# ----------------------------------------------------------------------------- simulation


def simulate(plant, controller: AbstractController, scenario: Scenario, x0=None) -> Trajectory:
    """One closed-loop run (a single `lax.scan`); `x0` defaults to `initial_state`.

    The controller sees $y_k = g(x_k) + v_k$ at every sample Ts; its input is saturated to
    [0, 1] before it reaches the plant. Pure: jit, vmap and grad go through.
    """
    if scenario.r.ndim != 2:
        raise ConfigError("simulate: a batched scenario needs `rollouts`, not `simulate`")
    p = _prepare(plant)
    x0 = initial_state(plant, scenario) if x0 is None else x0
    d0 = jax.tree.map(lambda a: a[0], scenario.d)
    y_first = p.measure(x0, d0)[0] + scenario.v[0]
    c0 = controller.init(y_first, scenario.r[0])

    def body(carry, inp):
        x, c = carry
        r, d, v = inp
        y_clean, temps = p.measure(x, d)
        y = y_clean + v
        u, c = controller.step(c, y, r)
        u = jnp.clip(u, 0.0, 1.0)
        return (p.step(x, u, d), c), (y, u, temps)

    _, (ys, us, temps) = jax.lax.scan(body, (x0, c0), (scenario.r, scenario.d, scenario.v))
    return Trajectory(y=ys, u=us, r=scenario.r, temperature=temps)


def rollouts(plant, controller: AbstractController, scenarios: Scenario, x0s=None, *,
             plant_axis: int | None = None) -> Trajectory:
    """A batch of closed-loop runs: vmap over the leading axis of `scenarios` (and `x0s`), and
    over a stacked batch of plants with `plant_axis=0` (one plant per rollout)."""
    if scenarios.r.ndim != 3:
        raise ConfigError("rollouts: scenarios need a leading rollout axis (make_scenario(..., n_rollouts=B))")
    if x0s is None:
        return jax.vmap(lambda pl, sc: simulate(pl, controller, sc),
                        in_axes=(plant_axis, 0))(plant, scenarios)
    return jax.vmap(lambda pl, sc, x0: simulate(pl, controller, sc, x0),
                    in_axes=(plant_axis, 0, 0))(plant, scenarios, x0s)


# ----------------------------------------------------------------------------- scenarios


def _as_key(key):
    if isinstance(key, (int, np.integer)):
        return jax.random.key(int(key))
    return key


def _printer_scenario(kind: str, printer: Printer, T: int, key, noise_std: float,
                      step_c: float):
    """r, d, v, y0 for one rollout on the printer (traceable in `key`)."""
    dt = printer.capacity.dtype
    n, ny = printer.zones, printer.n_outputs
    k_d, k_v, k_r, k_p = jax.random.split(key, 4)
    centre = jnp.full((n,), printer.window_centre, dt)
    extra = printer.area["setpoint"] if printer.has_areas else jnp.zeros((0,), dt)

    def full(bed):
        return jnp.concatenate([bed, extra.astype(dt)])

    if kind == "tracking":
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
                  reference: Printer | None = None) -> Scenario:
    """Build a thesis test scenario for `plant` (a batch with `n_rollouts`).

    **Arguments:**
    - `kind`: `"tracking"` (+`step_c` °C step on every bed channel from steady state below the
      window centre), `"powder"` (recoat layers at the window centre), `"print"` (recoat plus a
      per-layer laser exposure pattern), `"preheat"` (cold start at the surroundings, set point
      the window centre: start-up), `"ensemble"` (random start and set point within ±step_c/2,
      random layer phase, every disturbance the printer has; different per rollout).
    - `plant`: a `Printer` or a fitted `AbstractModel` (then `reference`, default a realistic
      printer with as many zones, provides the window, the surroundings and the output
      disturbances).
    - `duration` (s, default `DEFAULT_DURATION[kind]`), `key` (a PRNG key or integer seed),
      `noise_std` (white measurement noise, °C, added to the printer's `sensor_noise`).
    """
    if kind not in KINDS:
        raise ConfigError(f"make_scenario: unknown scenario `{kind}` (known: {', '.join(KINDS)})")
    duration = DEFAULT_DURATION[kind] if duration is None else duration
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration > 0):
        raise ConfigError(f"make_scenario: duration must be a positive number of seconds, got {duration!r}")
    if n_rollouts is not None and (not isinstance(n_rollouts, (int, np.integer)) or n_rollouts < 1):
        raise ConfigError(f"make_scenario: n_rollouts must be a positive integer, got {n_rollouts!r}")
    key = _as_key(key)
    if isinstance(plant, Printer):
        printer, model = plant, None
    elif isinstance(plant, AbstractModel):
        model = plant
        printer = reference if reference is not None else make_printer(
            int(model.n_outputs), REALISTIC_EFFECTS)
        if printer.n_outputs != model.n_outputs:
            raise ConfigError(f"make_scenario: the model has {model.n_outputs} outputs, the "
                              f"reference printer {printer.n_outputs}")
    else:
        raise ConfigError(f"make_scenario: unsupported plant {type(plant).__name__}")
    T = int(round(duration / printer.ts))
    if T < 2:
        raise ConfigError(f"make_scenario: duration {duration} s is shorter than two samples")

    keys = key if n_rollouts is None else jax.random.split(key, int(n_rollouts))
    r, d, v, y0 = _build_scenario(kind, printer, model, T, keys, float(noise_std),
                                  float(step_c), n_rollouts is not None)
    return Scenario(r=r, d=d, v=v, y0=y0, kind=kind, window=float(window),
                    edges=grid_edges(printer.zones), ts=printer.ts,
                    cold_start=(kind == "preheat"))


@eqx.filter_jit
def _build_scenario(kind, printer, model, T, keys, noise_std, step_c, batched):
    def one(k):
        r, d, v, y0 = _printer_scenario(kind, printer, T, k, noise_std, step_c)
        if model is not None:
            d = _model_disturbance(model, printer, d)
        return r, d, v, y0

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


# ----------------------------------------------------------------------------- metrics and cost


def _edge_index(edges):
    if not edges:
        return None
    e = np.asarray(edges)
    return e[:, 0], e[:, 1]


def _metrics_one(traj: Trajectory, scenario: Scenario) -> dict[str, Array]:
    ts, win = scenario.ts, scenario.window
    T = traj.temperature
    e = T - traj.r
    outside = jnp.any(jnp.abs(e) > win, axis=1)                       # (T,)
    n = outside.shape[0]
    k = jnp.arange(n)
    last_out = jnp.max(jnp.where(outside, k, -1))
    first_in = jnp.min(jnp.where(~outside, k, n))
    r_end = traj.r[-1]
    sgn = jnp.where(jnp.abs(r_end - scenario.y0) > 1e-9, jnp.sign(r_end - scenario.y0), 1.0)
    idx = _edge_index(scenario.edges)
    if idx is None:
        neigh = jnp.zeros((), T.dtype)
    else:
        neigh = jnp.max(jnp.abs(T[:, idx[0]] - T[:, idx[1]]))
    return {
        "mse": jnp.mean((traj.y - traj.r) ** 2),
        "mse_true": jnp.mean(e ** 2),
        "max_abs_error_C": jnp.max(jnp.abs(e)),
        "max_neighbour_diff_C": neigh,
        "time_outside_window_s": jnp.sum(outside) * ts,
        "overshoot_C": jnp.maximum(jnp.max(sgn * (T - r_end)), 0.0),
        "settling_time_s": (last_out + 1) * ts,
        "time_to_ready_s": first_in * ts,
        "effort": jnp.mean(traj.u),
        "input_variation": jnp.mean(jnp.abs(jnp.diff(traj.u, axis=0))),
    }


METRICS = ("mse", "mse_true", "max_abs_error_C", "max_neighbour_diff_C", "time_outside_window_s",
           "overshoot_C", "settling_time_s", "time_to_ready_s", "effort", "input_variation")


def metrics(traj: Trajectory, scenario: Scenario, *, per_rollout: bool = False) -> dict:
    """Test figures of a run (means over rollouts for a batch; `per_rollout=True` keeps them).

    `mse`: mean squared error of the *measured* outputs against the set point (the thesis'
    Tables 5.1–5.3); `mse_true`: the same on the true temperatures; `max_neighbour_diff_C`:
    largest temperature difference between grid neighbours (bed uniformity);
    `time_outside_window_s`: time with any zone outside set point ± `window`; `overshoot_C`:
    largest excursion beyond the final set point in the direction of the step;
    `settling_time_s`: time after which every zone stays inside the window (the run length if
    it never settles); `time_to_ready_s`: first time every zone is inside the window (ready
    to print; the run length if never); `effort`: mean input; `input_variation`: mean |Δu|.
    """
    vals = _metrics_jit(traj, scenario)
    if per_rollout:
        return {k: np.asarray(v) for k, v in vals.items()}
    return {k: float(np.mean(np.asarray(v))) for k, v in vals.items()}


@eqx.filter_jit
def _metrics_jit(traj, scenario):
    if traj.temperature.ndim == 3:
        return jax.vmap(_metrics_one, in_axes=(0, 0))(traj, scenario)
    return _metrics_one(traj, scenario)


DEFAULT_WEIGHTS = {"tracking": 1.0, "uniformity": 1.0, "effort": 1.0, "window": 1.0}


def cost(traj: Trajectory, scenario: Scenario, weights: Mapping[str, float] | None = None,
         *, smoothing: float = 0.1) -> Float[Array, ""]:
    """Smooth closed-loop cost, differentiable in everything that shaped `traj`:

    $J = w_t \\overline{e^2} + w_u \\overline{(T_i - T_j)^2}_{\\text{neighbours}}
       + w_e \\overline{\\Delta u^2} + w_w \\overline{\\sigma((|e| - \\text{window})/s)}$

    with $e = T - r$ on the true temperatures and $s$ = `smoothing` (°C); the last term is a
    smooth fraction of time (and zones) outside the window. Batches give the mean over rollouts.
    `weights` keys: tracking, uniformity, effort, window (defaults all 1).
    """
    w = _weights(weights)
    if traj.temperature.ndim == 3:
        return jnp.mean(jax.vmap(lambda t, s: cost(t, s, w, smoothing=smoothing))(traj, scenario))
    T, u = traj.temperature, traj.u
    e = T - traj.r
    J = w["tracking"] * jnp.mean(e ** 2)
    idx = _edge_index(scenario.edges)
    if idx is not None:
        J = J + w["uniformity"] * jnp.mean((T[:, idx[0]] - T[:, idx[1]]) ** 2)
    du = jnp.diff(u, axis=0)
    J = J + w["effort"] * jnp.mean(du ** 2)
    a = jnp.sqrt(e ** 2 + (0.1 * smoothing) ** 2)
    J = J + w["window"] * jnp.mean(jax.nn.sigmoid((a - scenario.window) / smoothing))
    return J


def _weights(weights):
    w = dict(DEFAULT_WEIGHTS)
    if weights is not None:
        bad = [k for k in weights if k not in DEFAULT_WEIGHTS]
        if bad:
            raise ConfigError(f"cost: unknown weight `{bad[0]}` (known: {', '.join(DEFAULT_WEIGHTS)})")
        w.update(weights)
    return w


def _is_zero(x) -> bool:
    return isinstance(x, (int, float)) and x == 0


def simulate_cost(plant, controller: AbstractController, scenario: Scenario,
                  weights: Mapping[str, float] | None = None, x0=None, *,
                  smoothing: float = 0.1, unroll: int | None = None) -> Float[Array, ""]:
    """`cost(simulate(...), scenario, weights)` accumulated inside the scan, without storing the
    trajectory: memory independent of the horizon (for large batches and long runs).

    With a `CompactScenario` (set-point step, sparse state jumps, in-scan noise) nothing of
    size `T` is read either: the leanest path, for fitted-model plants. `unroll` (of the
    time scan) defaults to 2 for a `CompactScenario`, 1 otherwise
    (`experiments/closedloop_lean_profile.py` measured 1-16)."""
    if isinstance(scenario, CompactScenario):
        return _compact_cost(plant, controller, scenario, weights, x0, smoothing=smoothing,
                             unroll=2 if unroll is None else unroll)
    unroll = 1 if unroll is None else unroll
    w = _weights(weights)
    p = _prepare(plant)
    x0 = initial_state(plant, scenario) if x0 is None else x0
    d0 = jax.tree.map(lambda a: a[0], scenario.d)
    y_first = p.measure(x0, d0)[0] + scenario.v[0]
    c0 = controller.init(y_first, scenario.r[0])
    idx = _edge_index(scenario.edges)
    eps = 0.1 * smoothing
    nu = _n_inputs(plant)
    zero = jnp.zeros((), scenario.r.dtype)

    def body(carry, inp):
        x, c, u_prev, first, acc = carry
        r, d, v = inp
        y_clean, temps = p.measure(x, d)
        u, c = controller.step(c, y_clean + v, r)
        u = jnp.clip(u, 0.0, 1.0)
        e = temps - r
        track = jnp.mean(e ** 2)
        # terms with a weight of (Python) zero are not computed at all
        unif = zero if (idx is None or _is_zero(w["uniformity"])) else \
            jnp.mean((temps[idx[0]] - temps[idx[1]]) ** 2)
        du = zero if _is_zero(w["effort"]) else jnp.where(first, 0.0, jnp.mean((u - u_prev) ** 2))
        win = zero if _is_zero(w["window"]) else jnp.mean(
            jax.nn.sigmoid((jnp.sqrt(e ** 2 + eps ** 2) - scenario.window) / smoothing))
        acc = acc + jnp.stack([track, unif, du, win])
        return (p.step(x, u, d), c, u, jnp.zeros((), bool), acc), None

    init = (x0, c0, jnp.zeros((nu,), scenario.r.dtype), jnp.ones((), bool),
            jnp.zeros((4,), scenario.r.dtype))
    (_, _, _, _, acc), _ = jax.lax.scan(body, init, (scenario.r, scenario.d, scenario.v),
                                        unroll=unroll)
    T = scenario.r.shape[0]
    J = w["tracking"] * acc[0] / T + w["window"] * acc[3] / T
    if idx is not None:
        J = J + w["uniformity"] * acc[1] / T
    return J + w["effort"] * acc[2] / max(T - 1, 1)


def rollout_costs(plant, controller: AbstractController, scenarios,
                  weights: Mapping[str, float] | None = None, x0s=None, *,
                  plant_axis: int | None = None, smoothing: float = 0.1,
                  unroll: int | None = None) -> Float[Array, " B"]:
    """Per-rollout `simulate_cost` over a batch of scenarios (and plants with `plant_axis=0`).

    `scenarios` is a batched `Scenario` or a batched `CompactScenario` (the lean path: no
    `(B, T, n)` input arrays at all)."""
    def one(pl, sc, x0=None):
        return simulate_cost(pl, controller, sc, weights, x0, smoothing=smoothing,
                             unroll=unroll)

    if x0s is None:
        return jax.vmap(one, in_axes=(plant_axis, 0))(plant, scenarios)
    return jax.vmap(one, in_axes=(plant_axis, 0, 0))(plant, scenarios, x0s)


def _n_inputs(plant) -> int:
    if isinstance(plant, (Printer, DiscretePrinter)):
        pr = plant if isinstance(plant, Printer) else plant.printer
        return pr.n_inputs
    return int(plant.n_inputs)


# ----------------------------------------------------------------------------- convenience


def _controller_from(controller, n: int, ts: float):
    if isinstance(controller, AbstractController):
        return controller
    if controller in ("untuned", "original"):
        from .control.pi import DiagonalPI
        return DiagonalPI.untuned(n, ts=ts)
    raise ConfigError(f"run: unknown controller {controller!r} (an AbstractController or 'untuned')")


def run(kind: str, controller, plant=None, *, rollouts: int = 8, duration: float | None = None,
        seed: int = 0, zones: int = 4, powder: str = "PA12") -> dict:
    """Simulate `rollouts` runs of scenario `kind` and report the metrics (means over rollouts).

    `plant` defaults to `make_printer(zones, REALISTIC_EFFECTS, powder=powder, seed=seed)`;
    `controller` is a controller module or `"untuned"` (the original identical PI per zone).

    **Returns:** `{"scenario", "controller", "zones", "rollouts", "duration", "seed", "metrics",
    "cost", "seconds"}`.
    """
    t0 = time.perf_counter()
    if not isinstance(rollouts, (int, np.integer)) or rollouts < 1:
        raise ConfigError(f"run: rollouts must be a positive integer, got {rollouts!r}")
    if plant is None:
        plant = make_printer(zones, REALISTIC_EFFECTS, powder=powder, seed=seed)
    ny = _n_outputs(plant)
    ts = plant.ts
    ctrl = _controller_from(controller, ny, ts)
    n_ctrl = getattr(ctrl, "zones", None)
    if n_ctrl is not None and n_ctrl != ny:
        raise ConfigError(f"run: the controller drives {n_ctrl} zones, the plant has {ny} outputs")
    sc = make_scenario(kind, plant, duration, jax.random.key(int(seed)), n_rollouts=int(rollouts))
    traj, J = _rollouts_and_cost(plant, ctrl, sc)
    m = metrics(traj, sc)
    return {"scenario": kind, "controller": type(ctrl).__name__ if not isinstance(controller, str)
            else controller, "zones": int(getattr(plant, "zones", ny)), "rollouts": int(rollouts),
            "duration": float(sc.n_samples * ts), "seed": int(seed), "metrics": m,
            "cost": float(J), "seconds": time.perf_counter() - t0}


def rollouts_and_cost(plant, controller, scenarios, weights=None):
    traj = rollouts(plant, controller, scenarios)
    return traj, cost(traj, scenarios, weights)


_rollouts_and_cost = eqx.filter_jit(rollouts_and_cost)


# ----------------------------------------------------------------------------- compact scenarios


class Events(eqx.Module):
    """Sparse impulses on a fitted model's measured signals `w`: at sample `time[e]`, channel
    `channel[e]` of `w` gets `size[e]` added for that one sample (a cold powder layer, a door
    opening, ...). Padding events use `time = -1` (never fires) or `size = 0`."""

    time: Int[Array, " E"]
    channel: Int[Array, " E"]
    size: Float[Array, " E"]


class CompactScenario(eqx.Module):
    """A fitted-model scenario held without any `(T, n)` array (a batch: a leading rollout axis
    on every array): the set point is a step from `r0` to `r1` at sample `t_step`, the measured
    signals are constant `w` plus sparse `events`, and the white measurement noise of std
    `noise_std` (static, °C) is drawn inside the scan from `key` (`jax.random.fold_in(key, k)`).
    `to_scenario()` expands it into the equivalent dense `Scenario` (same noise draws).
    `simulate_cost` and `rollout_costs` accept it: memory O(B·(n + E)) instead of O(B·T·n)."""

    r0: Float[Array, " ny"]
    r1: Float[Array, " ny"]
    t_step: Int[Array, ""]
    w: Float[Array, " nw"]
    events: Events
    y0: Float[Array, " ny"]
    key: Any = None
    n_samples: int = eqx.field(static=True, default=0)
    noise_std: float = eqx.field(static=True, default=0.0)
    kind: str = eqx.field(static=True, default="custom")
    window: float = eqx.field(static=True, default=WINDOW_C)
    edges: tuple = eqx.field(static=True, default=())
    ts: float = eqx.field(static=True, default=1.0)

    def __check_init__(self):
        if not (isinstance(self.n_samples, int) and self.n_samples >= 2):
            raise ConfigError(f"CompactScenario: n_samples must be an integer >= 2, got {self.n_samples!r}")
        if not (isinstance(self.noise_std, float) and self.noise_std >= 0):
            raise ConfigError(f"CompactScenario: noise_std must be a float >= 0, got {self.noise_std!r}")
        if self.noise_std > 0 and self.key is None:
            raise ConfigError("CompactScenario: noise_std > 0 needs a `key`")

    def _at(self, k):
        """Set point, measured signals and noise at sample `k` (traced)."""
        r = jnp.where(k >= self.t_step, self.r1, self.r0)
        hit = jnp.where(self.events.time == k, self.events.size, 0.0)
        w = self.w.at[self.events.channel].add(hit.astype(self.w.dtype)) if self.w.shape[0] \
            else self.w
        return r, w, self._noise(k)

    def _noise(self, k):
        if self.noise_std == 0.0:
            return jnp.zeros_like(self.r0)
        return self.noise_std * jax.random.normal(jax.random.fold_in(self.key, k),
                                                  self.r0.shape, self.r0.dtype)

    def to_scenario(self) -> Scenario:
        """The equivalent dense `Scenario` (for `simulate`, `rollouts`, `metrics`)."""
        if self.r0.ndim == 2:
            return jax.vmap(CompactScenario.to_scenario)(self)
        ks = jnp.arange(self.n_samples)
        r, w, v = jax.vmap(self._at)(ks)
        return Scenario(r=r, d=ModelDisturbance(w=w, dy=jnp.zeros_like(r)), v=v, y0=self.y0,
                        kind=self.kind, window=self.window, edges=self.edges, ts=self.ts)


def _compact_cost(plant, controller, sc: CompactScenario, weights, x0, *, smoothing, unroll):
    if sc.r0.ndim != 1:
        raise ConfigError("simulate_cost: a batched CompactScenario needs `rollout_costs`")
    if not isinstance(plant, AbstractModel):
        raise ConfigError(f"CompactScenario: needs a fitted-model plant, got {type(plant).__name__} "
                          "(use make_scenario for the printer)")
    w_ = _weights(weights)
    dt = sc.r0.dtype
    x0 = _model_steady_state(plant, sc.y0, sc.w) if x0 is None else x0
    ev = sc.events
    if ev.time.shape[-1] and sc.w.shape[-1] == 0:
        raise ConfigError("CompactScenario: events need measured signals `w` to act on (w is empty)")
    if type(plant).step is AbstractModel.step and type(plant).output is AbstractModel.output:
        # linear: x+ = A x + B u + c + G imp_k, built once outside the scan
        ss = plant.to_statespace()
        c = -ss.B @ ss.u0
        if ss.Bw.shape[1]:
            c = c + ss.Bw @ (sc.w - ss.w0)
        A, Bm, C, yc = ss.A, ss.B, ss.C, ss.y0
        n_ev = ev.time.shape[0] if ss.Bw.shape[1] else 0

        def measure(x):
            return yc + C @ x

        Bw = ss.Bw
        nw = Bw.shape[1]

        def step(x, u, k):
            xn = A @ x + Bm @ u + c
            if n_ev:   # the step's events: a scatter into w, then the shared Bw
                hit = jnp.where(ev.time == k, ev.size, 0.0).astype(dt)
                xn = xn + Bw @ jnp.zeros((nw,), dt).at[ev.channel].add(hit)
            return xn
    else:
        def measure(x):
            return plant.output(x)

        def step(x, u, k):
            w = sc._at(k)[1]
            return plant.step(x, u, w if w.shape[0] else None)

    y_first = measure(x0) + sc._noise(0)
    c0 = controller.init(y_first, jnp.where(0 >= sc.t_step, sc.r1, sc.r0))
    idx = _edge_index(sc.edges)
    eps = 0.1 * smoothing
    zero = jnp.zeros((), dt)
    use_unif = not (idx is None or _is_zero(w_["uniformity"]))
    use_du = not _is_zero(w_["effort"])
    use_win = not _is_zero(w_["window"])
    nu = int(plant.n_inputs)

    def body(carry, k):
        x, c, u_prev, acc = carry
        r = jnp.where(k >= sc.t_step, sc.r1, sc.r0)
        temps = measure(x)
        u, c = controller.step(c, temps + sc._noise(k), r)
        u = jnp.clip(u, 0.0, 1.0)
        e = temps - r
        track = jnp.mean(e ** 2)
        unif = jnp.mean((temps[idx[0]] - temps[idx[1]]) ** 2) if use_unif else zero
        du = jnp.where(k == 0, 0.0, jnp.mean((u - u_prev) ** 2)) if use_du else zero
        win = jnp.mean(jax.nn.sigmoid((jnp.sqrt(e ** 2 + eps ** 2) - sc.window) / smoothing)) \
            if use_win else zero
        acc = acc + jnp.stack([track, unif, du, win])
        return (step(x, u, k), c, u if use_du else u_prev, acc), None

    T = sc.n_samples
    init = (x0, c0, jnp.zeros((nu,), dt), jnp.zeros((4,), dt))
    (_, _, _, acc), _ = jax.lax.scan(body, init, jnp.arange(T), unroll=unroll)
    J = w_["tracking"] * acc[0] / T + w_["window"] * acc[3] / T
    if idx is not None:
        J = J + w_["uniformity"] * acc[1] / T
    return J + w_["effort"] * acc[2] / max(T - 1, 1)
