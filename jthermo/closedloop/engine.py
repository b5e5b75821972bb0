"""The closed-loop engine: plant adapters, `simulate` (one `lax.scan`), batched `rollouts`, the
lean paths that accumulate the cost (`simulate_cost`, `rollout_costs`, `CompactScenario`) or
every test figure (`simulate_metrics`, `rollout_metrics`) inside the scan, and `run`, the
one-call test of a controller (one compiled program, no `(B, T, n)` array)."""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..control._base import AbstractController
from ..data import same_ts
from ..errors import ConfigError
from ..models._base import AbstractModel
from ..printer import DiscretePrinter, Printer, make_printer
from ..printer.noise import NoiseStream
from ..runtime import simulate_compile
from ..stored import exported_call, exported_compile
from .checks import check_loop
from .compact import CompactScenario, compact_cost, model_steady_state
from .scenarios import (
    REALISTIC_EFFECTS,
    Scenario,
    Trajectory,
    make_scenario,
)
from .scoring import (
    RunningMetrics,
    cost,
    cost_weights,
    edge_index,
    is_static_zero,
    window_penalty,
)

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


#: the printer scenarios `make_scenario` draws without any recoat (tests/closedloop/
#: test_engine_substeps.py checks it): `run` integrates the printer in them without the recoat
#: sweep, in fewer sub-steps (`Printer.discretise(recoat=False)`)
RECOAT_FREE_KINDS = ("tracking", "preheat")


#: the signals of each printer scenario that are constant over the run by construction
#: (`scenarios._printer_scenario`: every kind holds its set points; tracking, powder and
#: preheat have no laser): `run` does not scan them (`_closed_loop`'s `held`)
HELD_SIGNALS = {"tracking": ("r", "laser"), "powder": ("r", "laser"), "preheat": ("r", "laser"),
                "print": ("r",), "ensemble": ("r",)}


def _prepare(plant, recoat: bool = True):
    if isinstance(plant, Printer):
        return _PrinterPlant(plant.discretise(recoat=recoat))
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
        return model_steady_state(plant, scenario.y0, scenario.d.w[0])
    raise ConfigError(f"closed loop: unsupported plant {type(plant).__name__}")


# ----------------------------------------------------------------------------- simulation


def _closed_loop(plant, controller: AbstractController, scenario: Scenario, x0, observe, acc0,
                 unroll: int = 1, recoat: bool = True, noise: NoiseStream | None = None,
                 held: tuple[str, ...] = ()):
    """The scanned loop shared by `simulate`, `simulate_cost` and `simulate_metrics`: at each
    sample k, `acc, out = observe(acc, k, y, u, temps, r)` sees the measured output, the
    saturated input, the true temperatures and the set point. Returns `(acc, outs)`.

    `noise` (a printer's `NoiseStream`): the measurement noise is drawn inside the scan, one
    sample at a time, instead of read from `scenario.v` (which is then not read at all).

    `held` (`HELD_SIGNALS`): signals the caller knows to be constant over the run (`"r"`, the
    set points; `"laser"`, a printer's laser power): their sample 0 is used at every sample
    instead of the `(T, n)` array being scanned, which XLA would otherwise form in memory
    (`run`'s printer scenarios: two `(T, B, n)` arrays, 118 MB each at T = 3600, B = 256,
    n = 16). The same values."""
    if scenario.r.ndim != 2:
        raise ConfigError("simulate: a batched scenario needs `rollouts`, not `simulate`")
    check_loop("simulate", plant, controller, scenario, x0)
    p = _prepare(plant, recoat)
    x0 = initial_state(plant, scenario) if x0 is None else x0
    d0 = jax.tree.map(lambda a: a[0], scenario.d)
    r_held = scenario.r[0] if "r" in held else None
    laser_held = d0.laser if "laser" in held else None
    d_seq = scenario.d if laser_held is None else dataclasses.replace(scenario.d, laser=None)
    if noise is None:
        v0, n0 = scenario.v[0], ()
        vs = scenario.v
    else:
        v0, n0 = noise.at(0, noise.init())
        vs = None
    y_first = p.measure(x0, d0)[0] + v0
    c0 = controller.init(y_first, scenario.r[0])

    def body(carry, inp):
        x, c, acc, nc = carry
        k, r, d, v, s = inp
        if r_held is not None:
            r = r_held
        if laser_held is not None:
            d = dataclasses.replace(d, laser=laser_held)
        if noise is not None:
            v, nc = noise.at(k, nc)
        y_clean, temps = p.measure(x, d)
        y = y_clean + v
        u, c = controller.step_schedule(c, y, r, s)
        u = jnp.clip(u, 0.0, 1.0)
        acc, out = observe(acc, k, y, u, temps, r)
        return (p.step(x, u, d), c, acc, nc), out

    ks = jnp.arange(scenario.r.shape[0])
    (_, _, acc, _), outs = jax.lax.scan(body, (x0, c0, acc0, n0),
                                        (ks, None if r_held is not None else scenario.r,
                                         d_seq, vs, scenario.s),
                                        unroll=unroll)
    return acc, outs


def simulate(plant, controller: AbstractController, scenario: Scenario, x0=None) -> Trajectory:
    """One closed-loop run (a single `lax.scan`); `x0` defaults to `initial_state`.

    The controller sees $y_k = g(x_k) + v_k$ at every sample Ts; its input is saturated to
    [0, 1] before it reaches the plant. Pure: jit, vmap and grad go through.
    """
    _, (ys, us, temps) = _closed_loop(plant, controller, scenario, x0,
                                      lambda acc, k, y, u, temps, r: (acc, (y, u, temps)), ())
    return Trajectory(y=ys, u=us, r=scenario.r, temperature=temps)


def simulate_metrics(plant, controller: AbstractController, scenario: Scenario,
                     weights: Mapping[str, float] | None = None, x0=None, *,
                     smoothing: float = 0.1, recoat: bool = True,
                     noise: NoiseStream | None = None,
                     held: tuple[str, ...] = ()) -> dict[str, Array]:
    """`metrics(simulate(...))` of one run (per-rollout values) and its `cost` (key `"cost"`),
    accumulated inside the scan (`RunningMetrics`): no `(T, n)` trajectory is stored, memory
    independent of the horizon. Equal to the dense figures to rounding.

    `recoat=False` (a printer scenario without any recoat, `RECOAT_FREE_KINDS`): the printer
    is integrated without the recoat sweep (`Printer.discretise(recoat=False)`), within 1e-3 °C
    of the full integration (measured by `python benchmarks/simulate_substeps.py`).

    `noise` (`Printer.noise_stream`): the measurement noise drawn inside the scan instead of
    read from `scenario.v` (`run` does this: the distribution of `scenario.v`, other draws).
    `held`: signals constant over the run, not scanned (`_closed_loop`)."""
    scorer = RunningMetrics.of(scenario, smoothing=smoothing)
    acc, _ = _closed_loop(plant, controller, scenario, x0,
                          lambda acc, k, y, u, temps, r: (scorer.update(acc, k, y, u, temps, r), None),
                          scorer.init(_n_inputs(plant)), recoat=recoat, noise=noise, held=held)
    return scorer.finish(acc, weights)


def rollout_metrics(plant, controller: AbstractController, scenarios: Scenario,
                    weights: Mapping[str, float] | None = None, x0s=None, *,
                    plant_axis: int | None = None, smoothing: float = 0.1,
                    recoat: bool = True, noise: NoiseStream | None = None,
                    held: tuple[str, ...] = ()) -> dict[str, Array]:
    """`simulate_metrics` over a batch of scenarios: each figure `(B,)` (the lean counterpart of
    `metrics(rollouts(...), per_rollout=True)` plus the per-rollout `cost`); `noise`: one
    `NoiseStream` per rollout (a leading rollout axis), drawn inside the scan."""
    if scenarios.r.ndim != 3:
        raise ConfigError("rollout_metrics: scenarios need a leading rollout axis "
                          "(make_scenario(..., n_rollouts=B))")

    def one(pl, sc, x0=None, nz=None):
        return simulate_metrics(pl, controller, sc, weights, x0, smoothing=smoothing,
                                recoat=recoat, noise=nz, held=held)

    return jax.vmap(one, in_axes=(plant_axis, 0, None if x0s is None else 0,
                                  None if noise is None else 0))(plant, scenarios, x0s, noise)


def rollouts(plant, controller: AbstractController, scenarios: Scenario, x0s=None, *,
             plant_axis: int | None = None) -> Trajectory:
    """A batch of closed-loop runs: vmap over the first axis of `scenarios` (and `x0s`), and
    over a stacked batch of plants with `plant_axis=0` (one plant per rollout)."""
    if scenarios.r.ndim != 3:
        raise ConfigError("rollouts: scenarios need a leading rollout axis (make_scenario(..., n_rollouts=B))")
    if x0s is None:
        return jax.vmap(lambda pl, sc: simulate(pl, controller, sc),
                        in_axes=(plant_axis, 0))(plant, scenarios)
    return jax.vmap(lambda pl, sc, x0: simulate(pl, controller, sc, x0),
                    in_axes=(plant_axis, 0, 0))(plant, scenarios, x0s)


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
        return compact_cost(plant, controller, scenario, weights, x0, smoothing=smoothing,
                             unroll=2 if unroll is None else unroll)
    unroll = 1 if unroll is None else unroll
    w = cost_weights(weights)
    idx = edge_index(scenario.edges)
    nu = _n_inputs(plant)
    zero = jnp.zeros((), scenario.r.dtype)

    def observe(carry, k, y, u, temps, r):
        u_prev, acc = carry
        e = temps - r
        track = jnp.mean(e ** 2)
        # terms with a weight of (Python) zero are not computed at all
        unif = zero if (idx is None or is_static_zero(w["uniformity"])) else \
            jnp.mean((temps[idx[0]] - temps[idx[1]]) ** 2)
        du = zero if is_static_zero(w["effort"]) else jnp.where(k == 0, 0.0, jnp.mean((u - u_prev) ** 2))
        win = zero if is_static_zero(w["window"]) else jnp.mean(
            window_penalty(e, scenario.window, smoothing))
        return (u, acc + jnp.stack([track, unif, du, win])), None

    init = (jnp.zeros((nu,), scenario.r.dtype), jnp.zeros((4,), scenario.r.dtype))
    (_, acc), _ = _closed_loop(plant, controller, scenario, x0, observe, init, unroll=unroll)
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
        from ..control.pi import DiagonalPI
        return DiagonalPI.untuned(n, ts=ts)
    raise ConfigError(f"run: unknown controller {controller!r} (an AbstractController or 'untuned')")


def run(kind: str, controller, plant=None, *, rollouts: int = 8, duration: float | None = None,
        seed: int = 0, zones: int = 4, powder: str = "PA12", scenario_kw=None) -> dict:
    """Simulate `rollouts` runs of scenario `kind` and report the metrics (means over rollouts).

    `plant` defaults to `make_printer(zones, REALISTIC_EFFECTS, powder=powder, seed=seed)`;
    `controller` is a controller module or `"untuned"` (the original identical PI per zone);
    `scenario_kw` goes to `make_scenario` (a fitted model's `envelope` and `setpoint`).
    The figures come from `rollout_metrics` (accumulated in the scan: no trajectory is stored;
    equal to `metrics` of the stored rollouts to rounding), the printer's scenarios drawn
    inside the same compiled call, their measurement noise inside the scan (`rollout_noise`:
    the distribution of `make_scenario`'s noise, other draws; `run_scenario` materialises the
    scenarios `run` simulates). In the printer's recoat-free scenarios (`tracking`,
    `preheat`) the printer is integrated without the recoat sweep (`recoat=False` of
    `rollout_metrics`): MSE within 3e-5 relative of the full integration.

    **Returns:** `{"scenario", "controller", "zones", "rollouts", "duration", "seed", "metrics",
    "setpoints", "ts", "cost", "seconds"}`.
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
    c_ts = getattr(ctrl, "ts", None)
    if isinstance(c_ts, (int, float)) and not same_ts(c_ts, ts):
        raise ConfigError(f"run: the controller runs at a sample time of {c_ts:g} s, the plant "
                          f"at {ts:g} s")
    if isinstance(plant, Printer) and not scenario_kw:
        # the printer's scenarios are drawn inside the same compiled call, its key too
        # traced once per cache: later processes load the exported program (`runtime`)
        out = exported_call(_seeded_metrics_fn, _seeded_args(kind, plant, ctrl, duration, seed, rollouts),
                            _quick_seeded_metrics(), compiler_options=simulate_compile())
    else:
        sc = make_scenario(kind, plant, duration, jax.random.key(int(seed)),
                           n_rollouts=int(rollouts), **dict(scenario_kw or {}))
        out = run_metrics(plant, ctrl, sc, kind not in RECOAT_FREE_KINDS)
    vals, r0, n_samples = jax.device_get(out)   # one transfer to the host
    J = vals.pop("cost")
    return {"scenario": kind, "controller": type(ctrl).__name__ if not isinstance(controller, str)
            else controller, "zones": int(getattr(plant, "zones", ny)), "rollouts": int(rollouts),
            "duration": float(n_samples * ts), "seed": int(seed),
            "metrics": {k: float(v) for k, v in vals.items()},
            "setpoints": np.asarray(r0).tolist(), "ts": float(ts),
            "cost": float(J), "seconds": time.perf_counter() - t0}


def _seeded_args(kind, plant, ctrl, duration, seed, rollouts) -> tuple:
    """The arguments of `run`'s compiled printer program (`_seeded_metrics_fn`)."""
    return kind, plant, ctrl, duration, np.asarray(int(seed), np.int64), int(rollouts)


def prepare_run(kind: str, controller, plant: Printer, *, rollouts: int = 8,
                duration: float | None = None) -> bool:
    """Compile, without running, the program `run(kind, c, plant, rollouts=..., duration=...)`
    calls for any controller `c` of `controller`'s structure (the same type, static fields
    and array shapes; the gains may differ): e.g. in a thread while the real controller is
    designed, on a cold cache the compile then overlaps the design (`stored.exported_compile`).
    True when prepared; False where `run` would not use that program (not a printer, the
    cache off) or preparation failed, which never affects `run` itself."""
    if not isinstance(plant, Printer):
        return False
    ctrl = _controller_from(controller, _n_outputs(plant), plant.ts)
    return exported_compile(_seeded_metrics_fn, _seeded_args(kind, plant, ctrl, duration, 0, rollouts),
                            compiler_options=simulate_compile())


@eqx.filter_jit
def run_metrics(plant, controller, scenarios, recoat=True, noise=None, held=()):
    """Means over rollouts of `rollout_metrics` (the figures `run` reports, and the cost), the
    first set point and the run length: one compiled call, no `(B, T, n)` output."""
    vals = rollout_metrics(plant, controller, scenarios, recoat=recoat, noise=noise, held=held)
    return {k: jnp.mean(v) for k, v in vals.items()}, scenarios.r[0, 0], scenarios.n_samples


#: white measurement noise of `run`'s printer scenarios, °C (`make_scenario`'s `noise_std`)
RUN_NOISE_STD = 0.05


def rollout_noise(plant: Printer, key, n_rollouts: int, noise_std: float = RUN_NOISE_STD):
    """The `NoiseStream` of each rollout of `make_scenario(kind, plant, ..., key,
    n_rollouts=n_rollouts, noise_std=noise_std)` (a leading rollout axis), with the noise's
    distribution (`printer.noise`): rollout b's stream is keyed by the second of four keys
    split from the b-th of `split(key, n_rollouts)`, the key of the scenario's own noise."""
    def one(k):
        return plant.noise_stream(jax.random.split(k, 4)[1], noise_std)

    return jax.vmap(one)(jax.random.split(key, n_rollouts))


@eqx.filter_jit
def run_scenario(kind: str, plant: Printer, duration, key, n_rollouts: int) -> Scenario:
    """The batch of printer scenarios `run(kind, ..., plant, rollouts=n_rollouts, seed=...)`
    simulates, materialised (for checks and figures): `make_scenario`'s with the measurement
    noise `v` of `run`'s in-scan streams (`rollout_noise`) in place of its own draw."""
    sc = make_scenario(kind, plant, duration, key, n_rollouts=n_rollouts, noise_std=RUN_NOISE_STD)
    T = sc.r.shape[1]
    v = jax.vmap(lambda s: s.sample(T))(rollout_noise(plant, key, n_rollouts))
    return eqx.tree_at(lambda s: s.v, sc, v)


def _scenario_metrics_fn(kind, plant, controller, duration, key, n_rollouts):
    """`run_metrics` of `make_scenario(kind, plant, duration, key, n_rollouts=...)`, the
    scenarios drawn inside the same program (`kind`, `duration`, `n_rollouts` static; the key
    traced: one compile for every seed). The measurement noise is drawn inside the scan,
    sample by sample (`rollout_noise`: the scenario's noise distribution, about a quarter of
    its cost): the scenario's `(B, T, ny)` noise is never formed (XLA drops it unread)."""
    sc = make_scenario(kind, plant, duration, key, n_rollouts=n_rollouts, noise_std=RUN_NOISE_STD)
    noise = rollout_noise(plant, key, n_rollouts)
    return run_metrics(plant, controller, sc, kind not in RECOAT_FREE_KINDS, noise,
                        HELD_SIGNALS.get(kind, ()))


scenario_metrics = eqx.filter_jit(_scenario_metrics_fn)


def _seeded_metrics_fn(kind, plant, controller, duration, seed, n_rollouts):
    """`_scenario_metrics_fn` with its key `jax.random.key(seed)` made inside the program from
    the 0-d int64 `seed` (traced: one compile for every seed): the same key, bit for bit,
    without the two small eager programs `jax.random.key` runs outside a trace."""
    return _scenario_metrics_fn(kind, plant, controller, duration, jax.random.key(seed),
                                n_rollouts)


@functools.cache
def _quick_scenario_metrics():
    """`scenario_metrics` compiled with `runtime.simulate_compile()` options, as `run` calls
    it where its exported program cannot serve: compiled once per cache and run once per
    command (the same figures to 1e-16 relative)."""
    return eqx.filter_jit(_scenario_metrics_fn, compiler_options=simulate_compile())


@functools.cache
def _quick_seeded_metrics():
    """`_seeded_metrics_fn` compiled as `_quick_scenario_metrics` (`run`'s fallback)."""
    return eqx.filter_jit(_seeded_metrics_fn, compiler_options=simulate_compile())


def rollouts_and_cost(plant, controller, scenarios, weights=None):
    traj = rollouts(plant, controller, scenarios)
    return traj, cost(traj, scenarios, weights)
