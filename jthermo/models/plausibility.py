"""Physical plausibility of a fitted thermal model: does a heater step move each sensor the way
heat does?

A fit can score well and still be a model no heater has: the Klipper hot-end's second-order
state-space fits (`experiments/own_plant.py`) fall by 4–10 °C in the first seconds after the
heater switches on, then rise. `plausibility` looks at the step response of each output to each
input and reports, per pair:

- an *inverse response*: the response first moves against its final direction,
  $\\max_k(-\\operatorname{sign}(G_{ij})\\,s_{ij}(k))\\,\\Delta u_j > \\tau_i$, with $s_{ij}$ the
  unit-step response, $G_{ij}$ the static gain, $\\Delta u_j$ the input's span and the
  threshold $\\tau_i = \\max(3\\sigma_i, 0.01 \\max_k |s_{ij}(k)|\\,\\Delta u_j)$ from the
  output's noise level $\\sigma_i$ (°C);
- a *heater that cools its own sensor*: $G_{ii}\\,\\Delta u_i < -\\tau_i$ on a square model.

Plus an unstable model (a heater step that never settles). Findings are warnings, not errors:
the fit stands, the user decides. The response is computed on the host in float64 over a window
of five times the slowest time constant (bounded, see `window`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..errors import ModelError
from . import polynomial_numpy
from ._base import AbstractModel
from .envelope import Envelope
from .statespace_numpy import realise

#: an excursion counts when it exceeds this many noise standard deviations ...
NOISE_SIGMAS = 3.0
#: ... and this share of the response's largest magnitude (numerical wiggles of a noise-free fit)
RELATIVE_FLOOR = 0.01
#: the window covers this many of the slowest time constants ...
TIME_CONSTANTS = 5.0
#: ... within these sample counts, and within this many multiply-adds of the state recursion
MIN_SAMPLES, MAX_SAMPLES, MAX_WORK = 64, 20_000, 2e8


def window(A: np.ndarray, nu: int) -> int:
    """Samples of the step response checked: $5\\tau_{max}/T_s$ from the slowest pole
    ($\\tau/T_s = -1/\\ln|p|$), clipped to [`MIN_SAMPLES`, `MAX_SAMPLES`] and to `MAX_WORK`
    multiply-adds of the recursion $x_{k+1} = A x_k + B$ with `nu` columns."""
    nx = A.shape[0]
    rho = float(np.max(np.abs(np.linalg.eigvals(A)))) if nx else 0.0
    return window_length(rho, nx, nu)


def window_length(rho: float, nx: int, nu: int) -> int:
    """`window` from the largest pole magnitude `rho` and the state dimension `nx`."""
    if nx == 0:
        return MIN_SAMPLES
    n = MAX_SAMPLES if rho >= 1.0 else (TIME_CONSTANTS / -math.log(max(rho, 1e-300)))
    cap = max(MIN_SAMPLES, int(MAX_WORK / max(nx * nx * nu, 1)))
    return int(min(max(math.ceil(n), MIN_SAMPLES), MAX_SAMPLES, cap))


def step_responses(A, B, C, D, n: int) -> np.ndarray:
    """Unit-step responses $s(k) = C x_k + D$, $x_{k+1} = A x_k + B$, $x_0 = 0$: `(n, ny, nu)`."""
    x = np.zeros((A.shape[0], B.shape[1]))
    out = np.empty((n, C.shape[0], B.shape[1]))
    for k in range(n):
        out[k] = C @ x + D
        x = A @ x + B
    return out


def _names(names, n, prefix):
    return [str(v) for v in names] if names else [f"{prefix}{i + 1}" for i in range(n)]


def _responses(model: AbstractModel, span_arg):
    """Step responses scaled by the input span `(n, ny, nu)`, static gains `(ny, nu)` (the final
    value when unstable), stability and the window length: from the model's NumPy filters for a
    diagonal-A polynomial model (`polynomial_numpy`: nothing to compile), otherwise from its
    state-space realisation on the host."""
    if polynomial_numpy.supported(model):
        rho = polynomial_numpy.spectral_radius(model)
        if not np.isfinite(rho):
            raise ModelError("plausibility: the model has non-finite matrices")
        nu = model.n_inputs
        span = _span(span_arg, nu)
        n = window_length(rho, polynomial_numpy.n_states(model), nu)
        s = polynomial_numpy.step_responses(model, n) * span
        stable = rho < 1.0
        gain = polynomial_numpy.dc_gain(model) * span if stable else s[-1]
        return s, gain, stable, n
    ss = realise(model)
    A, B, C, D = (np.asarray(m, dtype=np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    if not all(np.all(np.isfinite(m)) for m in (A, B, C, D)):
        raise ModelError("plausibility: the model has non-finite matrices")
    span = _span(span_arg, B.shape[1])
    n = window(A, B.shape[1])
    s = step_responses(A, B, C, D, n) * span                        # °C, (n, ny, nu)
    stable = A.shape[0] == 0 or float(np.max(np.abs(np.linalg.eigvals(A)))) < 1.0
    if stable:      # G(1) = C (I - A)^{-1} B + D, on the host
        gain = (C @ np.linalg.solve(np.eye(A.shape[0]) - A, B) + D) * span
    else:
        gain = s[-1]
    return s, gain, stable, n


def _span(span, nu: int) -> np.ndarray:
    span = np.broadcast_to(np.asarray(1.0 if span is None else span, np.float64), (nu,))
    if not (np.all(np.isfinite(span)) and np.all(span > 0)):
        raise ModelError("plausibility: noise_std must be >= 0 and input_span > 0, all finite")
    return span


def plausibility(model: AbstractModel, *, noise_std: Sequence[float] | float | None = None,
                 input_span: Sequence[float] | float | None = None,
                 input_names: Sequence[str] = (), output_names: Sequence[str] = ()) -> dict:
    """Check that heater steps move the sensors the way heat does (module docstring).

    **Arguments:**
    - `model`: any `AbstractModel` (its state-space realisation is used).
    - `noise_std`: each output's measurement-noise std, °C (one value or one per output;
      `Envelope.noise_std` of a fit); default 0 (the relative floor alone).
    - `input_span`: each input's step size, power fraction (default 1: off to full power).
    - `input_names`, `output_names`: channel names for the warnings.

    **Returns:** `{"stable", "window_s", "pairs", "warnings"}`: `pairs` one dict per
    (output, input) with `output`, `input`, `dc_gain` (°C per unit input), `wrong_way_C`
    (largest move against the final direction for the step `input_span`, °C), `wrong_way_at_s`,
    `threshold_C`, `inverse_response` and `cools_own_sensor` (bools); `warnings` one line each.
    """
    s, gain, stable, n = _responses(model, input_span)
    ny, nu = gain.shape
    span = _span(input_span, nu)
    sigma = np.broadcast_to(np.asarray(0.0 if noise_std is None else noise_std, np.float64), (ny,))
    if not (np.all(np.isfinite(sigma)) and np.all(sigma >= 0)):
        raise ModelError("plausibility: noise_std must be >= 0 and input_span > 0, all finite")
    ts = float(model.ts)
    ynames, unames = _names(output_names, ny, "y"), _names(input_names, nu, "u")
    pairs, warnings = [], []
    if not stable:
        warnings.append("the model is not stable: a heater step never settles")
    for i in range(ny):
        for j in range(nu):
            r = s[:, i, j]
            tau = max(NOISE_SIGMAS * sigma[i], RELATIVE_FLOOR * float(np.max(np.abs(r))))
            direction = math.copysign(1.0, gain[i, j])
            against = -direction * r
            k = int(np.argmax(against))
            wrong = max(float(against[k]), 0.0) + 0.0      # no -0.0
            inverse = bool(abs(gain[i, j]) > tau and wrong > tau)
            cools = bool(ny == nu and i == j and gain[i, j] < -tau)
            pairs.append({"output": ynames[i], "input": unames[j], "dc_gain": float(gain[i, j] / span[j]),
                          "wrong_way_C": wrong, "wrong_way_at_s": k * ts, "threshold_C": tau,
                          "inverse_response": inverse, "cools_own_sensor": cools})
            if inverse:
                warnings.append(
                    f"{unames[j]} -> {ynames[i]}: a step of {span[j]:g} first moves the output "
                    f"{'down' if direction > 0 else 'up'} by {wrong:.3g} °C (at {k * ts:.3g} s; "
                    f"threshold {tau:.3g} °C) before it settles {'up' if direction > 0 else 'down'}"
                    f": an inverse response no heater has")
            if cools:
                warnings.append(f"{unames[j]} -> {ynames[i]}: static gain {gain[i, j] / span[j]:.3g} "
                                f"°C per unit input: a heater that cools its own sensor")
    return {"stable": stable, "window_s": n * ts, "pairs": pairs, "warnings": warnings}


def check_fit(model: AbstractModel, envelope: Envelope | None = None, *,
              input_names: Sequence[str] = (), output_names: Sequence[str] = ()) -> dict:
    """`plausibility` of a fitted model with its recording's noise level (`envelope.noise_std`)
    and input span (`envelope.u_max - envelope.u_min`); without an envelope, the defaults."""
    if envelope is None:
        return plausibility(model, input_names=input_names, output_names=output_names)
    span = np.asarray(envelope.u_max, np.float64) - np.asarray(envelope.u_min, np.float64)
    return plausibility(model, noise_std=envelope.noise_std, input_span=span,
                        input_names=input_names, output_names=output_names)


#: the steady states may miss the recorded range by this share of it (plus the noise) ...
COVERAGE_SHARE = 0.05


#: a measured signal whose name holds one of these is a logged set point
SETPOINT_WORDS = ("target", "setpoint", "set_point")


def is_setpoint_signal(name: str) -> bool:
    """A logged set point (`w_<heater>_target_C`, as printer logs carry, or `w_T1_setpoint`, as
    TCLab MPC runs do): neither a plant input nor a disturbance of it."""
    return any(word in str(name).lower() for word in SETPOINT_WORDS)


def coverage(model: AbstractModel, u_range, w_range=None, y_range=None, noise_std=None,
             output_names: Sequence[str] = ()) -> dict:
    """Do the model's steady states over the recorded inputs and measured signals cover the
    recorded temperatures?

    The steady output $y_{ss}(u, w) = y_0 + G(u - u_0) + G_w(w - w_0)$ is linear, so over the
    box of recorded input ranges (`u_range`, `(2, nu)`: minima, maxima) and signal ranges
    (`w_range`, `(2, nw)`) its extremes lie at the corners. Output $i$ is covered when
    $\\min y_{ss,i} \\le y_{min,i} + \\tau_i$ and $\\max y_{ss,i} \\ge y_{max,i} - \\tau_i$ with
    $\\tau_i = 3\\sigma_i + 0.05\\,(y_{max,i} - y_{min,i})$. An unstable model covers nothing.

    **Returns:** `{"covered", "steady_min", "steady_max", "warnings"}`.
    """
    from .envelope import steady_gains

    ss = model.to_statespace()
    A = np.asarray(ss.A, np.float64)
    ur = np.asarray(u_range, np.float64).reshape(2, -1)
    nw = int(ss.Bw.shape[1])
    wr = (np.zeros((2, 0)) if nw == 0 or w_range is None
          else np.asarray(w_range, np.float64).reshape(2, -1)[:, :nw])
    yr = np.asarray(y_range, np.float64).reshape(2, -1)
    ny = yr.shape[1]
    sigma = np.broadcast_to(np.asarray(0.0 if noise_std is None else noise_std, np.float64), (ny,))
    names = _names(output_names, ny, "y")
    if A.shape[0] and float(np.max(np.abs(np.linalg.eigvals(A)))) >= 1.0:
        return {"covered": False, "steady_min": None, "steady_max": None,
                "warnings": ["the model is not stable: it has no steady states"]}
    # Each output's extremes over the box, term by term: y0 - G u0 - Gw w0 plus, per input,
    # the smaller (larger) of G_ij u_min,j and G_ij u_max,j. Exact for any number of inputs.
    _, G, Gw = steady_gains(ss)
    u0, w0, y0 = (np.asarray(v, np.float64).reshape(-1) for v in (ss.u0, ss.w0, ss.y0))
    base = y0 - G @ u0
    lo_u, hi_u = np.minimum(G * ur[0], G * ur[1]).sum(1), np.maximum(G * ur[0], G * ur[1]).sum(1)
    if nw and wr.shape[1] == nw:
        base = base - Gw @ w0
        lo_u = lo_u + np.minimum(Gw * wr[0], Gw * wr[1]).sum(1)
        hi_u = hi_u + np.maximum(Gw * wr[0], Gw * wr[1]).sum(1)
    lo, hi = base + lo_u, base + hi_u
    tau = NOISE_SIGMAS * sigma + COVERAGE_SHARE * (yr[1] - yr[0])
    warnings = []
    for i in range(ny):
        if lo[i] > yr[0, i] + tau[i] or hi[i] < yr[1, i] - tau[i]:
            warnings.append(f"{names[i]}: the model's steady states span {lo[i]:.1f} to "
                            f"{hi[i]:.1f} °C over the recorded inputs; the recording spans "
                            f"{yr[0, i]:.1f} to {yr[1, i]:.1f} °C")
    return {"covered": not warnings, "steady_min": lo.tolist(), "steady_max": hi.tolist(),
            "warnings": warnings}


def starts_at_rest(y, noise_std=None) -> bool:
    """Does the record start at rest: every output's first reading within the coverage
    tolerance ($3\\sigma_i + 0.05\\,\\mathrm{range}_i$) of its lowest? A heater record that does
    started with the heaters off, so its first reading is the steady state at zero input (a
    cold start, a step test from ambient); `heat_check` counts zero input among the recorded
    ones, or the start would be a temperature the heaters' recorded powers cannot hold."""
    y = np.asarray(y, np.float64)
    sigma = np.broadcast_to(np.asarray(0.0 if noise_std is None else noise_std, np.float64),
                            (y.shape[1],))
    tau = NOISE_SIGMAS * sigma + COVERAGE_SHARE * np.ptp(y, axis=0)
    return bool(y.shape[0] and np.all(y[0] <= y.min(axis=0) + tau))


def heat_check(model: AbstractModel, data, envelope: Envelope | None = None) -> dict:
    """Is `model` a plant heat could be, judged on its recording `data` (an `IOData`)?
    The step-response findings of `check_fit` (stable, no heater cooling its sensor, no inverse
    response beyond the noise), the sign of every static gain (no heater lowers any sensor's
    steady temperature beyond the noise and `COVERAGE_SHARE` of the strongest heater effect on
    that sensor) and `coverage` of the recorded temperatures, with
    zero input counted among the recorded ones when the record starts at rest
    (`starts_at_rest`).

    **Returns:** `{"plausible", "warnings", "shape_ok"}`; `shape_ok` is True when every warning
    is one of coverage (the model is a heated body, but its steady states miss part of the
    recorded range), so that a fit with orders the user gave can be kept and reported.
    """
    env = Envelope.from_data(data) if envelope is None else envelope
    found = check_fit(model, env, input_names=data.input_names, output_names=data.output_names)
    warnings = list(found["warnings"])
    sigma = np.asarray(env.noise_std, np.float64)
    names_y, names_u = data.output_names, data.input_names
    # A heater lowers a sensor's steady temperature when its effect over its recorded range is
    # negative beyond the noise and `COVERAGE_SHARE` of the largest heater effect on that sensor:
    # at many zones a far heater's true effect is nil and its estimate scatters around zero.
    effect = np.zeros((data.n_outputs, data.n_inputs))
    for p, (i, j) in zip(found["pairs"], np.ndindex(data.n_outputs, data.n_inputs)):
        effect[i, j] = p["dc_gain"] * (env.u_max[j] - env.u_min[j])
    strongest = np.max(np.abs(effect), axis=1) if effect.size else np.zeros(data.n_outputs)
    for p, (i, j) in zip(found["pairs"], np.ndindex(data.n_outputs, data.n_inputs)):
        tol = max(NOISE_SIGMAS * sigma[i], p["threshold_C"], COVERAGE_SHARE * strongest[i])
        if effect[i, j] < -tol and not p["cools_own_sensor"]:
            warnings.append(f"{names_u[j]} -> {names_y[i]}: static gain {p['dc_gain']:.3g} °C per "
                            "unit input: a heater that lowers a sensor's steady temperature")
    shape_ok = not warnings
    if found["stable"]:
        u = np.asarray(data.u, np.float64)
        w = np.asarray(data.w, np.float64)
        y = np.asarray(data.y, np.float64)
        u_lo = u.min(0)
        if starts_at_rest(y, sigma):     # its first reading is the heaters-off steady state
            u_lo = np.minimum(u_lo, 0.0)
        cov = coverage(model, np.stack([u_lo, u.max(0)]),
                       np.stack([w.min(0), w.max(0)]) if w.shape[1] else None,
                       np.stack([y.min(0), y.max(0)]), sigma, names_y)
        warnings += cov["warnings"]
    return {"plausible": not warnings, "warnings": warnings, "shape_ok": shape_ok}
