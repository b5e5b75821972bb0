"""Classical design rules: step-response models, lambda tuning, RGA, decoupling, and `design`.

Design runs once, eagerly, on a fitted model (any `AbstractModel`: it is converted to its
innovations state space); what it returns are controllers whose gains are array leaves, ready
for closed-loop simulation and gradient tuning.

References: Glad & Ljung, *Reglerteknik* (2006) for lambda tuning and decoupling;
Skogestad & Postlethwaite (2005), §3.4 for the RGA.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from ..errors import ControlError
from ..models._base import AbstractModel, StateSpace

# --------------------------------------------------------------------------------------
# three-parameter step-response model  G(s) = K e^{-sL} / (1 + sT)   (thesis eq. 2.10)
# --------------------------------------------------------------------------------------


class StepModel(NamedTuple):
    """Per-channel three-parameter model $K e^{-sL}/(1+sT)$: gain (°C per unit input), lag L (s)
    and time constant T (s), each of shape `(n,)`."""

    K: np.ndarray
    L: np.ndarray
    T: np.ndarray


def _as_ss(model) -> StateSpace:
    if not isinstance(model, AbstractModel):
        raise ControlError(f"design: expected a jthermo model, got {type(model).__name__}")
    ss = model.to_statespace()
    if ss.B.shape[1] != ss.C.shape[0]:
        raise ControlError(
            f"design: needs as many inputs as outputs, got nu={ss.B.shape[1]}, ny={ss.C.shape[0]}")
    rho = float(np.max(np.abs(np.linalg.eigvals(np.asarray(ss.A, np.float64)))))
    if not math.isfinite(rho) or rho >= 1.0:
        raise ControlError(f"design: the model is unstable (spectral radius {rho:.4g}); "
                           "design needs a stable model")
    return ss


def _horizon(ss: StateSpace, max_n: int = 20000) -> int:
    """Samples needed for the slowest pole to settle (about 7 time constants)."""
    rho = float(np.max(np.abs(np.linalg.eigvals(np.asarray(ss.A, np.float64)))))
    if rho < 1e-12:
        return 50
    tau = -1.0 / math.log(rho)
    return int(min(max(50, math.ceil(7 * tau) + 10), max_n))


def _np_step(A, B, C, D, n):
    """Unit step responses (n, ny, nu) of a numpy state space (deviation from rest)."""
    nx, nu = B.shape
    x = np.zeros((nx, nu))
    out = np.empty((n, C.shape[0], nu))
    for k in range(n):
        out[k] = C @ x + D
        x = A @ x + B
    return out


def fit_step_model(s: np.ndarray, ts: float, K: float | None = None) -> tuple[float, float, float]:
    """Three-parameter model from one step response `s` (n,) sampled every `ts` s.

    Two-point method: $T = 1.5 (t_{63} - t_{28})$, $L = t_{63} - T$ (Seborg et al. 2011, §7.2),
    with crossing times interpolated linearly between samples. Exact for a first-order lag.
    `K` is the static gain (default: the last sample of `s`).
    """
    s = np.asarray(s, np.float64)
    K = float(s[-1]) if K is None else float(K)
    if not math.isfinite(K) or K <= 0.0:
        raise ControlError(f"design: step response ends at {K:.4g}; the loop needs a positive gain")

    def crossing(level):
        idx = int(np.argmax(s >= level * K))
        if idx == 0:
            return 0.0
        s0, s1 = s[idx - 1], s[idx]
        return (idx - 1 + (level * K - s0) / (s1 - s0)) * ts

    t28, t63 = crossing(0.283), crossing(0.632)
    T = max(1.5 * (t63 - t28), 1e-3 * ts)
    L = max(t63 - T, 0.0)
    return K, L, T


def step_models(model, transform: np.ndarray | None = None) -> StepModel:
    """Three-parameter model of each diagonal channel of $G W$ (W = `transform`, default I)."""
    ss = _as_ss(model)
    A, B, C, D = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    if transform is not None:
        B, D = B @ transform, D @ transform
    S = _np_step(A, B, C, D, _horizon(ss))
    G0 = C @ np.linalg.solve(np.eye(A.shape[0]) - A, B) + D
    K, L, T = zip(*(fit_step_model(S[:, i, i], ss.ts, G0[i, i]) for i in range(S.shape[1])))
    return StepModel(np.array(K), np.array(L), np.array(T))


def lambda_gains(sm: StepModel, lam=None) -> tuple[np.ndarray, np.ndarray]:
    """Lambda tuning of a PI on $K e^{-sL}/(1+sT)$: $K_p = T/(K(\\lambda + L))$, $T_i = T$.

    `lam` is the desired closed-loop time constant in s (scalar or per channel); default
    $\\lambda = T$ (closed loop as fast as the open loop). Returns `(kp, ti)`.
    """
    lam_arr = sm.T if lam is None else np.broadcast_to(np.asarray(lam, np.float64), sm.T.shape)
    if np.any(~np.isfinite(lam_arr)) or np.any(lam_arr <= 0):
        raise ControlError(f"design: lambda must be positive, got {lam}")
    kp = sm.T / (sm.K * (lam_arr + sm.L))
    return kp, sm.T.copy()


# --------------------------------------------------------------------------------------
# interaction analysis and decoupling
# --------------------------------------------------------------------------------------


def rga(G) -> np.ndarray:
    """Relative gain array $\\Lambda = G \\circ (G^{-1})^T$ of a square gain matrix."""
    G = np.asarray(G, np.float64)
    if G.ndim != 2 or G.shape[0] != G.shape[1]:
        raise ControlError(f"rga: needs a square gain matrix, got shape {G.shape}")
    try:
        Gi = np.linalg.inv(G)
    except np.linalg.LinAlgError:
        raise ControlError("rga: the gain matrix is singular") from None
    return G * Gi.T


def needs_decoupling(model, tol: float = 0.5) -> bool:
    """RGA decision (thesis §4.2): decouple when a diagonal relative gain is farther than `tol`
    from 1 (strong interaction) or an off-diagonal one exceeds `tol` in magnitude."""
    lam = rga(np.asarray(_as_ss(model).dcgain()))
    off = lam - np.diag(np.diag(lam))
    return bool(np.max(np.abs(np.diag(lam) - 1.0)) > tol or np.max(np.abs(off)) > tol)


def decoupling_matrix(model, kind: str = "CB") -> np.ndarray:
    """Static decoupler $W_1$: `"CB"` gives $(CB)^{-1}$ (thesis eq. 2.14), `"G0"` gives
    $G(0)^{-1}$ (eq. 2.13)."""
    ss = _as_ss(model)
    if kind == "CB":
        M = np.asarray(ss.C @ ss.B + ss.D, np.float64)
    elif kind == "G0":
        M = np.asarray(ss.dcgain(), np.float64)
    else:
        raise ControlError(f"decoupling_matrix: kind must be 'CB' or 'G0', got {kind!r}")
    cond = np.linalg.cond(M)
    if not math.isfinite(cond) or cond > 1e10:
        raise ControlError(f"decoupling_matrix: {kind} is singular (condition number {cond:.3g})")
    return np.linalg.inv(M)


def zeros_stable(model, margin: float = 0.02) -> bool:
    """True when the one-step inverse of the model is stable: the eigenvalues of
    $A - B (CB)^{-1} C A$ (the transmission zeros of a relative-degree-one model) lie inside
    the circle of radius `1 - margin`."""
    ss = _as_ss(model)
    A, B, C = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C))
    CB = C @ B
    if np.linalg.cond(CB) > 1e10:
        return False
    Z = A - B @ np.linalg.solve(CB, C @ A)
    ev = np.linalg.eigvals(Z)
    return bool(np.all(np.isfinite(ev)) and np.max(np.abs(ev)) < 1.0 - margin)


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
    ss = _as_ss(model)
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
        r = np.broadcast_to(np.asarray(setpoint, np.float64), y0.shape)
        u1 = u1 + np.linalg.lstsq(G1, r - y1, rcond=None)[0]
        y1 = r
    if not (np.all(np.isfinite(u1)) and np.all(np.isfinite(y1))):
        raise ControlError("design: the model's equilibrium at the design point is not finite")
    dt = ss.A.dtype
    return StateSpace(ss.A, ss.B, ss.C, ss.D, ss.K, ts=ss.ts, Bw=ss.Bw, u0=_f(u1, dt),
                      w0=_f(w1, dt), y0=_f(y1, dt))


def operating_point(model) -> tuple[np.ndarray, np.ndarray]:
    """`(u0, y0)` of the model's operating point (power fraction, °C)."""
    ss = _as_ss(model)
    return np.asarray(ss.u0, np.float64), np.asarray(ss.y0, np.float64)


def _f(x, dtype=None):
    return jnp.asarray(np.asarray(x, np.float64), dtype)


# --------------------------------------------------------------------------------------
# the dispatcher
# --------------------------------------------------------------------------------------

FAMILIES = ("pi_untuned", "pi_lambda", "pi_decoupled", "feedforward", "imc", "lqg", "gated_pi")
# short names users type, e.g. `jthermo tune --controller pi` (PI means the lambda-tuned design)
ALIASES = {"pi": "pi_lambda", "lambda": "pi_lambda", "diagonal_pi": "pi_lambda",
           "untuned": "pi_untuned", "original": "pi_untuned", "decoupled": "pi_decoupled",
           "ff": "feedforward", "gated": "gated_pi", "lqg_integral": "lqg"}


def canonical_family(name: str) -> str:
    """The `FAMILIES` name of a family name or alias (`ALIASES`); unknown names unchanged."""
    key = str(name).strip().lower().replace("-", "_")
    return ALIASES.get(key, key)


def design(family: str, model, *, setpoint=None, **kwargs):
    """Design a controller of the named family from a model, at `design_point(model,
    setpoint)`: the model's nominal operating point, or the equilibrium that holds it at
    `setpoint` (°C) when one is given.

    **Arguments:**
    - `family`: one of `FAMILIES` — `"pi_untuned"` (identical PI per zone, the original
      solution), `"pi_lambda"` (lambda-tuned diagonal PI), `"pi_decoupled"` (W1 = (CB)⁻¹ by
      default), `"feedforward"` (neutral by default), `"imc"`, `"lqg"`, `"gated_pi"`
      (lambda-tuned PI used inside a ±band around the set point).
    - `model`: any fitted `AbstractModel` (or StateSpace).
    - keyword arguments go to the family's design function.

    **Returns:** an `AbstractController`.
    """
    # local imports: these modules import this one
    from . import decoupled, feedforward, imc, lqg
    from .gated import gated as _gated

    family = canonical_family(family)
    if setpoint is not None or hasattr(model, "nominal_point"):
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
        return _gated(decoupled.design_lambda_pi(model, **kwargs), band, u_outside,
                           width=width)
    raise ControlError(f"design: unknown controller family {family!r}; choose one of "
                       + ", ".join(FAMILIES))
