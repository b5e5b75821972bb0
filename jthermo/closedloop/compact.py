"""Compact scenarios: a fitted-model scenario held without any `(T, n)` array (a set-point step,
constant measured signals plus sparse events, white noise drawn inside the scan), and its cost
accumulated in one `lax.scan` (`compact_cost`, what `engine.simulate_cost` runs for it)."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..errors import ConfigError
from ..models._base import AbstractModel
from .scenarios import WINDOW_C, ModelDisturbance, Scenario
from .scoring import cost_weights, edge_index, is_static_zero, window_penalty


def model_steady_state(model: AbstractModel, y0, w):
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


def compact_cost(plant, controller, sc: CompactScenario, weights, x0, *, smoothing, unroll):
    if sc.r0.ndim != 1:
        raise ConfigError("simulate_cost: a batched CompactScenario needs `rollout_costs`")
    if not isinstance(plant, AbstractModel):
        raise ConfigError(f"CompactScenario: needs a fitted-model plant, got {type(plant).__name__} "
                          "(use make_scenario for the printer)")
    w_ = cost_weights(weights)
    dt = sc.r0.dtype
    x0 = model_steady_state(plant, sc.y0, sc.w) if x0 is None else x0
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
    idx = edge_index(sc.edges)
    zero = jnp.zeros((), dt)
    use_unif = not (idx is None or is_static_zero(w_["uniformity"]))
    use_du = not is_static_zero(w_["effort"])
    use_win = not is_static_zero(w_["window"])
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
        win = jnp.mean(window_penalty(e, sc.window, smoothing)) if use_win else zero
        acc = acc + jnp.stack([track, unif, du, win])
        return (step(x, u, k), c, u if use_du else u_prev, acc), None

    T = sc.n_samples
    init = (x0, c0, jnp.zeros((nu,), dt), jnp.zeros((4,), dt))
    (_, _, _, acc), _ = jax.lax.scan(body, init, jnp.arange(T), unroll=unroll)
    J = w_["tracking"] * acc[0] / T + w_["window"] * acc[3] / T
    if idx is not None:
        J = J + w_["uniformity"] * acc[1] / T
    return J + w_["effort"] * acc[2] / max(T - 1, 1)
