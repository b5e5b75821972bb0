"""`design`: a controller of a named family from a model, at the design point.

Design runs once, eagerly, on a fitted model (any `AbstractModel`: it is converted to its
innovations state space); what it returns are controllers whose gains are array leaves, ready
for closed-loop simulation and gradient tuning. The rules the families share (step-response
models, lambda tuning, RGA, decoupling) live in `rules` and are re-exported here.
"""

from __future__ import annotations

import numpy as np

from .._checks import per_output
from ..errors import ControlError
from ..models._base import StateSpace
from . import decoupled, feedforward, imc, lqg, relay
from .mimo_pi import mimo_from
from .schedule_ff import with_schedule
from .gated import gated
from .rules import (
    StepModel,
    as_array,
    as_state_space,
    decoupling_matrix,
    fit_step_model,
    lambda_gains,
    needs_decoupling,
    operating_point,
    rga,
    step_models,
    zeros_stable,
)


def design_point(model, setpoint=None, signals=None, inputs=None) -> StateSpace:
    """The model's state space moved, along its own equilibria, to the point a design needs.

    A linear model is the same model at any of its equilibria $(u^*, w^*, y^*)$,
    $y^* = y_0 + G(1)(u^* - u_0) + G_w(1)(w^* - w_0)$, $G(1) = C(I - A)^{-1}B + D$,
    $G_w(1) = C(I - A)^{-1}B_w$; the design's bias, static gains and observer start are taken
    there. $u^*$ = `inputs` and $w^*$ = `signals` default to the model's `nominal_point()` where
    it has one (a fitted grey-box bed: the estimation data's mean heater input and measured
    surroundings, so it is not designed at rest at 0 °C), else to its own $u_0$, $w_0$. With a
    `setpoint` $r$ (°C, scalar or per output), $u^* \\leftarrow u^* + G(1)^{-1}(r - y^*)$
    (least squares when not square) and $y^* = r$: the input that holds the model at $r$.
    """
    ss = as_state_space(model)
    A, B, C, D, Bw = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D, ss.Bw))
    u0, w0, y0 = (np.asarray(v, np.float64) for v in (ss.u0, ss.w0, ss.y0))
    nominal = model.nominal_point() if hasattr(model, "nominal_point") else (None, None)
    inputs = nominal[0] if inputs is None else inputs
    signals = nominal[1] if signals is None else signals
    inv = np.linalg.solve(np.eye(A.shape[0]) - A, np.concatenate([B, Bw], axis=1))
    G1, Gw1 = C @ inv[:, :B.shape[1]] + D, C @ inv[:, B.shape[1]:]
    u1 = u0 if inputs is None else np.broadcast_to(np.asarray(inputs, np.float64), u0.shape)
    w1 = w0 if signals is None else np.broadcast_to(np.asarray(signals, np.float64), w0.shape)
    y1 = y0 + G1 @ (u1 - u0) + Gw1 @ (w1 - w0)
    if setpoint is not None:
        per_output("design", "setpoint", setpoint, y0.size)
        r = np.broadcast_to(np.asarray(setpoint, np.float64), y0.shape)
        u1 = u1 + np.linalg.lstsq(G1, r - y1, rcond=None)[0]
        y1 = r
    if not (np.all(np.isfinite(u1)) and np.all(np.isfinite(y1))):
        raise ControlError("design: the model's equilibrium at the design point is not finite")
    dt = ss.A.dtype
    return StateSpace(ss.A, ss.B, ss.C, ss.D, ss.K, ts=ss.ts, Bw=ss.Bw, u0=as_array(u1, dt),
                      w0=as_array(w1, dt), y0=as_array(y1, dt))


# --------------------------------------------------------------------------------------
# the dispatcher
# --------------------------------------------------------------------------------------

FAMILIES = ("pi_untuned", "pi_lambda", "pi_decoupled", "feedforward", "imc", "lqg", "gated_pi",
            "pi_mimo", "pi_ff", "lqg_ff", "pid_relay")
# short names users type, e.g. `jthermo tune --controller pi` (PI means the lambda-tuned design)
ALIASES = {"pi": "pi_lambda", "lambda": "pi_lambda", "diagonal_pi": "pi_lambda",
           "untuned": "pi_untuned", "original": "pi_untuned", "decoupled": "pi_decoupled",
           "ff": "feedforward", "gated": "gated_pi", "lqg_integral": "lqg",
           "mimo_pi": "pi_mimo", "mimo": "pi_mimo", "pi_schedule": "pi_ff",
           "relay": "pid_relay", "pid": "pid_relay", "zn": "pid_relay"}


def canonical_family(name: str) -> str:
    """The `FAMILIES` name of a family name or alias (`ALIASES`); unknown names unchanged."""
    key = str(name).strip().lower().replace("-", "_")
    return ALIASES.get(key, key)


def design(family: str, model, *, setpoint=None, **kwargs):
    """Design a controller of the named family from a model, at `design_point(model,
    setpoint)`: the equilibrium that holds the model at `setpoint` (°C, scalar or per
    output), with its input as every family's bias; without one, the model's nominal
    operating point (a fitted model's: where its recording was made — pass the set point the
    loop will run at, e.g. `Envelope.default_setpoint(model)`).

    **Arguments:**
    - `family`: one of `FAMILIES` — `"pi_untuned"` (identical PI per zone, the original
      solution), `"pi_lambda"` (lambda-tuned diagonal PI), `"pi_decoupled"` (W1 = (CB)⁻¹ by
      default), `"feedforward"` (neutral by default), `"imc"`, `"lqg"`, `"gated_pi"`
      (lambda-tuned PI used inside a ±band around the set point), `"pi_mimo"` (full-matrix
      MIMO PI, starting as the PI `start=` (default `"pi_untuned"`, the best classical PI on
      the printer in `experiments/results/schedule_ff_study.json`; or `"pi_lambda"`,
      `"pi_decoupled"`); `edges=` pairs of zones for a neighbour-sparse one), `"pi_ff"` (that MIMO PI plus the schedule feed-forward, `taps=`), `"lqg_ff"`
      (the LQG plus the schedule feed-forward), `"pid_relay"` (the firmware's relay auto-tune
      run on the model, then Ziegler–Nichols PID: `relay.design_pid_relay`).
    - `model`: any fitted `AbstractModel` (or StateSpace).
    - keyword arguments go to the family's design function.

    **Returns:** an `AbstractController`.
    """
    family = canonical_family(family)
    # every family is designed at an equilibrium of the model, with that equilibrium's bias
    model = design_point(model, setpoint)
    if family == "pi_untuned":
        return decoupled.design_untuned_pi(model, **kwargs)
    if family == "pi_lambda":
        return decoupled.design_lambda_pi(model, **kwargs)
    if family == "pi_decoupled":
        return decoupled.design_decoupled_pi(model, **kwargs)
    if family == "feedforward":
        return feedforward.design_feedforward(model, **kwargs)
    if family == "imc":
        return imc.design_imc(model, **kwargs)
    if family == "lqg":
        return lqg.design_lqg(model, **kwargs)
    if family == "gated_pi":
        band = kwargs.pop("band", 3.0)
        u_outside = kwargs.pop("u_outside", None)
        width = kwargs.pop("width", None)
        return gated(decoupled.design_lambda_pi(model, **kwargs), band, u_outside, width=width)
    if family in ("pi_mimo", "pi_ff"):
        taps = kwargs.pop("taps", None)
        edges = kwargs.pop("edges", None)
        start = canonical_family(kwargs.pop("start", "pi_untuned"))
        starts = {"pi_untuned": decoupled.design_untuned_pi,
                  "pi_lambda": decoupled.design_lambda_pi,
                  "pi_decoupled": decoupled.design_decoupled_pi}
        if start not in starts:
            raise ControlError(f"design: a MIMO PI starts from one of {', '.join(starts)}, "
                               f"got {start!r}")
        fb = mimo_from(starts[start](model, **kwargs), edges=edges)
        return fb if family == "pi_mimo" else with_schedule(fb, *(() if taps is None else (taps,)))
    if family == "pid_relay":
        return relay.design_pid_relay(model, **kwargs)
    if family == "lqg_ff":
        taps = kwargs.pop("taps", None)
        return with_schedule(lqg.design_lqg(model, **kwargs), *(() if taps is None else (taps,)))
    raise ControlError(f"design: unknown controller family {family!r}; choose one of "
                       + ", ".join(FAMILIES))


# the rules' names stay importable from here, where they lived before `rules`
__all__ = [
    "ALIASES",
    "FAMILIES",
    "StepModel",
    "canonical_family",
    "decoupling_matrix",
    "design",
    "design_point",
    "fit_step_model",
    "lambda_gains",
    "needs_decoupling",
    "operating_point",
    "rga",
    "step_models",
    "zeros_stable",
]
