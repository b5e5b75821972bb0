"""Scoring closed-loop runs: the test figures (`metrics`) and the smooth, differentiable cost
(`cost`) with its weights, shared by the dense and the lean (in-scan) paths."""

from __future__ import annotations

from collections.abc import Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..control._base import U_MAX, U_MIN
from ..errors import ConfigError
from .scenarios import WINDOW_C, Scenario, Trajectory

# ----------------------------------------------------------------------------- metrics and cost


def edge_index(edges):
    """`(i, j)` index arrays of the grid-neighbour pairs `edges`, or None without any."""
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
    sgn = step_sign(r_end, scenario.y0)
    idx = edge_index(scenario.edges)
    if idx is None:
        neigh = jnp.zeros((), T.dtype)
    else:
        neigh = jnp.max(jnp.abs(T[:, idx[0]] - T[:, idx[1]]))
    du = jnp.diff(traj.u, axis=0)
    return with_deprecated({
        "mse": jnp.mean((traj.y - traj.r) ** 2),
        "mse_true": jnp.mean(e ** 2),
        "max_abs_error_C": jnp.max(jnp.abs(e)),
        "max_neighbour_diff_C": neigh,
        "time_outside_window_s": jnp.sum(outside) * ts,
        "overshoot_C": jnp.maximum(jnp.max(sgn * (T - r_end)), 0.0),
        "settling_time_s": (last_out + 1) * ts,
        "time_to_ready_s": first_in * ts,
        "mean_input": jnp.mean(traj.u),
        "input_variation": jnp.mean(jnp.abs(du)),
        "mean_sq_input_change": jnp.mean(du ** 2),
        "saturated_fraction": jnp.mean(saturated(traj.u).astype(traj.u.dtype)),
    })


def step_sign(r_end, y0):
    """Direction of the set-point step per output: sign(r_end - y0), +1 where there is none."""
    return jnp.where(jnp.abs(r_end - y0) > 1e-9, jnp.sign(r_end - y0), 1.0)


def saturated(u):
    """Inputs within `SATURATED` of a limit (boolean, elementwise)."""
    return (u <= U_MIN + SATURATED) | (u >= U_MAX - SATURATED)


def window_penalty(e, window: float, smoothing: float):
    """Smooth indicator of $|e|$ > `window`: $\\sigma((\\sqrt{e^2 + (s/10)^2} - w)/s)$,
    elementwise, $s$ = `smoothing` (°C)."""
    return jax.nn.sigmoid((jnp.sqrt(e ** 2 + (0.1 * smoothing) ** 2) - window) / smoothing)


#: renamed metrics still reported under their old name for one release: `{old: new}` (`effort`
#: was the mean input, while the cost term `effort` is the mean squared input change)
DEPRECATED_METRICS = {"effort": "mean_input"}
METRICS = ("mse", "mse_true", "max_abs_error_C", "max_neighbour_diff_C", "time_outside_window_s",
           "overshoot_C", "settling_time_s", "time_to_ready_s", "mean_input", "input_variation",
           "mean_sq_input_change", "saturated_fraction", *DEPRECATED_METRICS)


def with_deprecated(vals: dict) -> dict:
    """`vals` with each `DEPRECATED_METRICS` old name added as a copy of its new name."""
    return {**vals, **{old: vals[new] for old, new in DEPRECATED_METRICS.items()}}


#: an input this close to a limit (power fraction) counts as saturated
SATURATED = 1e-6


def metrics(traj: Trajectory, scenario: Scenario, *, per_rollout: bool = False) -> dict:
    """Test figures of a run (means over rollouts for a batch; `per_rollout=True` keeps them).

    `mse`: mean squared error of the *measured* outputs against the set point (the thesis'
    Tables 5.1–5.3); `mse_true`: the same on the true temperatures; `max_neighbour_diff_C`:
    largest temperature difference between grid neighbours (bed uniformity);
    `time_outside_window_s`: time with any zone outside set point ± `window`; `overshoot_C`:
    largest excursion beyond the final set point in the direction of the step;
    `settling_time_s`: time after which every zone stays inside the window (the run length if
    it never settles); `time_to_ready_s`: first time every zone is inside the window (ready
    to print; the run length if never); `mean_input`: mean input (power fraction);
    `input_variation`: mean $|\\Delta u|$; `mean_sq_input_change`: mean $\\Delta u^2$, the cost's
    `effort` term before its weight; `saturated_fraction`: share of samples (and inputs) at an
    input limit. `effort` is the old name of `mean_input`, kept for one release
    (`DEPRECATED_METRICS`).
    """
    vals = _metrics_jit(traj, scenario)
    if per_rollout:
        return {k: np.asarray(v) for k, v in vals.items()}
    return {k: float(np.mean(np.asarray(v))) for k, v in vals.items()}


def metric_arrays(traj: Trajectory, scenario: Scenario) -> dict[str, Array]:
    """`metrics(traj, scenario, per_rollout=True)` as traceable arrays (inside `jax.jit`)."""
    if traj.temperature.ndim == 3:
        return jax.vmap(_metrics_one, in_axes=(0, 0))(traj, scenario)
    return _metrics_one(traj, scenario)


_metrics_jit = eqx.filter_jit(metric_arrays)


class RunningMetrics(eqx.Module):
    """`metrics` and `cost` of one rollout computed on the fly, one sample at a time inside the
    scan, so no `(T, n)` trajectory is stored: running sums (squared errors, inputs, |Δu|,
    Δu², the smooth window term), running extremes (|e|, neighbour difference, overshoot) and
    the running indices of the last sample outside the window and the first inside.

    `init` gives the carry, `update` adds sample k, `finish` gives the figures; they equal
    `metrics(simulate(...))` and `cost(...)` of the same run to rounding
    (`tests/closedloop/test_engine_lean_metrics.py`)."""

    r_end: Float[Array, " ny"]        # final set point, °C
    sign: Float[Array, " ny"]         # direction of the step (+1 without one)
    n_samples: int = eqx.field(static=True)
    window: float = eqx.field(static=True, default=WINDOW_C)
    edges: tuple = eqx.field(static=True, default=())
    ts: float = eqx.field(static=True, default=1.0)
    smoothing: float = eqx.field(static=True, default=0.1)

    @classmethod
    def of(cls, scenario: Scenario, *, smoothing: float = 0.1) -> RunningMetrics:
        """The scorer of one (unbatched) dense `scenario`."""
        r_end = scenario.r[-1]
        return cls(r_end=r_end, sign=step_sign(r_end, scenario.y0), n_samples=scenario.n_samples,
                   window=scenario.window, edges=scenario.edges, ts=scenario.ts,
                   smoothing=smoothing)

    def init(self, nu: int) -> dict[str, Array]:
        dt = self.r_end.dtype
        z = jnp.zeros((), dt)
        return {"sq_meas": z, "sq_true": z, "max_abs": z, "max_neigh": z, "overshoot": z - jnp.inf,
                "n_out": z, "last_out": jnp.asarray(-1), "first_in": jnp.asarray(self.n_samples),
                "u_sum": z, "du_abs": z, "n_sat": z, "unif": z, "du_sq": z, "win": z,
                "u_prev": jnp.zeros((nu,), dt)}

    def update(self, acc: dict, k, y, u, temps, r) -> dict[str, Array]:
        """`acc` with sample `k` (measured `y`, input `u`, true `temps`, set point `r`) added."""
        e = temps - r
        out = jnp.any(jnp.abs(e) > self.window)
        first = k == 0
        du = u - acc["u_prev"]
        idx = edge_index(self.edges)
        if idx is None:
            neigh = unif = jnp.zeros((), e.dtype)
        else:
            diff = temps[idx[0]] - temps[idx[1]]
            neigh, unif = jnp.max(jnp.abs(diff)), jnp.sum(diff ** 2)
        return {"sq_meas": acc["sq_meas"] + jnp.sum((y - r) ** 2),
                "sq_true": acc["sq_true"] + jnp.sum(e ** 2),
                "max_abs": jnp.maximum(acc["max_abs"], jnp.max(jnp.abs(e))),
                "max_neigh": jnp.maximum(acc["max_neigh"], neigh),
                "overshoot": jnp.maximum(acc["overshoot"], jnp.max(self.sign * (temps - self.r_end))),
                "n_out": acc["n_out"] + out,
                "last_out": jnp.where(out, k, acc["last_out"]),
                "first_in": jnp.where(out, acc["first_in"], jnp.minimum(acc["first_in"], k)),
                "u_sum": acc["u_sum"] + jnp.sum(u),
                "du_abs": acc["du_abs"] + jnp.where(first, 0.0, jnp.sum(jnp.abs(du))),
                "n_sat": acc["n_sat"] + jnp.sum(saturated(u)),
                "unif": acc["unif"] + unif,
                "du_sq": acc["du_sq"] + jnp.where(first, 0.0, jnp.sum(du ** 2)),
                "win": acc["win"] + jnp.sum(window_penalty(e, self.window, self.smoothing)),
                "u_prev": u}

    def finish(self, acc: dict, weights: Mapping[str, float] | None = None) -> dict[str, Array]:
        """The `METRICS` of the run and its `cost` (key `"cost"`) from the final carry."""
        w = cost_weights(weights)
        T, ts = self.n_samples, self.ts
        ny, nu = self.r_end.shape[0], acc["u_prev"].shape[0]
        mse_true = acc["sq_true"] / (T * ny)
        J = w["tracking"] * mse_true + w["effort"] * acc["du_sq"] / ((T - 1) * nu) \
            + w["window"] * acc["win"] / (T * ny)
        if self.edges:
            J = J + w["uniformity"] * acc["unif"] / (T * len(self.edges))
        vals = {"mse": acc["sq_meas"] / (T * ny), "mse_true": mse_true,
                "max_abs_error_C": acc["max_abs"], "max_neighbour_diff_C": acc["max_neigh"],
                "time_outside_window_s": acc["n_out"] * ts,
                "overshoot_C": jnp.maximum(acc["overshoot"], 0.0),
                "settling_time_s": (acc["last_out"] + 1) * ts,
                "time_to_ready_s": acc["first_in"] * ts,
                "mean_input": acc["u_sum"] / (T * nu),
                "input_variation": acc["du_abs"] / ((T - 1) * nu),
                "mean_sq_input_change": acc["du_sq"] / ((T - 1) * nu),
                "saturated_fraction": acc["n_sat"] / (T * nu), "cost": J}
        return with_deprecated(vals)


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
    w = cost_weights(weights)
    if traj.temperature.ndim == 3:
        return jnp.mean(jax.vmap(lambda t, s: cost(t, s, w, smoothing=smoothing))(traj, scenario))
    T, u = traj.temperature, traj.u
    e = T - traj.r
    J = w["tracking"] * jnp.mean(e ** 2)
    idx = edge_index(scenario.edges)
    if idx is not None:
        J = J + w["uniformity"] * jnp.mean((T[:, idx[0]] - T[:, idx[1]]) ** 2)
    du = jnp.diff(u, axis=0)
    J = J + w["effort"] * jnp.mean(du ** 2)
    J = J + w["window"] * jnp.mean(window_penalty(e, scenario.window, smoothing))
    return J


def cost_weights(weights):
    """`DEFAULT_WEIGHTS` updated with `weights`; an unknown key raises `ConfigError`."""
    w = dict(DEFAULT_WEIGHTS)
    if weights is not None:
        bad = [k for k in weights if k not in DEFAULT_WEIGHTS]
        if bad:
            raise ConfigError(f"cost: unknown weight `{bad[0]}` (known: {', '.join(DEFAULT_WEIGHTS)})")
        w.update(weights)
    return w


def is_static_zero(x) -> bool:
    """A weight that is a Python zero: its cost term is left out of the scan altogether."""
    return isinstance(x, (int, float)) and x == 0

