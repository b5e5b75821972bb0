"""Classical design rules shared by the controller families: model → operating point →
step-response models → gains, with the interaction analysis (RGA) and the static decoupler.

Everything here runs once, eagerly, in numpy on a fitted model (any `AbstractModel`,
converted to its innovations state space); `as_array` turns the results into the array
leaves of a controller.

References: Glad & Ljung, *Reglerteknik* (2006) for lambda tuning and decoupling;
Skogestad & Postlethwaite (2005), §3.4 for the RGA.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import numpy as np

from ..errors import ControlError
from ..models._base import AbstractModel, StateSpace

# --------------------------------------------------------------------------------------
# the model and its operating point
# --------------------------------------------------------------------------------------


def as_state_space(model) -> StateSpace:
    """The model's state space, checked for design: square (as many inputs as outputs) and
    stable (spectral radius below 1)."""
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


def as_array(x, dtype=None):
    """A controller leaf: `x` as a JAX array, through float64 (then `dtype` if given). NumPy
    converts and the array is transferred (`jnp.asarray` would run an eager copy program:
    traced, lowered and looked up in the compilation cache on every call of the command)."""
    a = np.asarray(x, np.float64)
    return jax.device_put(a if dtype is None else a.astype(dtype))


def operating_point(model) -> tuple[np.ndarray, np.ndarray]:
    """`(u0, y0)` of the model's operating point (power fraction, °C)."""
    ss = as_state_space(model)
    return np.asarray(ss.u0, np.float64), np.asarray(ss.y0, np.float64)


def bias_input(model, u_bias=None) -> np.ndarray:
    """A PI's input at zero integrator: `u_bias` (broadcast per input), or the model's
    operating-point input."""
    u0, _ = operating_point(model)
    return u0 if u_bias is None else np.broadcast_to(u_bias, u0.shape)


def dcgain_inverse(ss: StateSpace, who: str) -> np.ndarray:
    """$G(0)^{-1}$, the static inverse of the model (`who` names the caller in the error)."""
    G0 = np.asarray(ss.dcgain(), np.float64)
    if np.linalg.cond(G0) > 1e10:
        raise ControlError(f"{who}: G(0) is singular")
    return np.linalg.inv(G0)


# --------------------------------------------------------------------------------------
# three-parameter step-response model  G(s) = K e^{-sL} / (1 + sT)   (thesis eq. 2.10)
# --------------------------------------------------------------------------------------


class StepModel(NamedTuple):
    """Per-channel three-parameter model $K e^{-sL}/(1+sT)$: gain (°C per unit input), lag L (s)
    and time constant T (s), each of shape `(n,)`."""

    K: np.ndarray
    L: np.ndarray
    T: np.ndarray


def step_horizon(ss: StateSpace, max_n: int = 20000) -> int:
    """Samples needed for the slowest pole to settle (about 7 time constants)."""
    rho = float(np.max(np.abs(np.linalg.eigvals(np.asarray(ss.A, np.float64)))))
    if rho < 1e-12:
        return 50
    tau = -1.0 / math.log(rho)
    return int(min(max(50, math.ceil(7 * tau) + 10), max_n))


def step_responses(A, B, C, D, n, until=None, check_every: int = 64):
    """Unit step responses (n, ny, nu) of a numpy state space (deviation from rest).

    `until` (ny,): stop, checking every `check_every` samples, once every diagonal response
    $s_{ii}$ has reached `until[i]` (then fewer than `n` samples come back: the samples
    computed are the same numbers)."""
    nx, nu = B.shape
    x = np.zeros((nx, nu))
    out = np.empty((n, C.shape[0], nu))
    for k in range(n):
        out[k] = C @ x + D
        x = A @ x + B
        if until is not None and (k + 1) % check_every == 0 and _reached(out[: k + 1], until):
            return out[: k + 1]
    return out


def _reached(S: np.ndarray, levels: np.ndarray) -> bool:
    """Whether every diagonal step response in `S` (k, ny, nu) has a sample >= `levels`."""
    diag = np.diagonal(S, axis1=1, axis2=2)
    return bool(np.all(np.any(diag >= levels, axis=0)))


#: the fractions of the static gain whose first crossings `fit_step_model` times (28.3 %, 63.2 %)
FIT_LEVELS = (0.283, 0.632)


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

    t28, t63 = (crossing(level) for level in FIT_LEVELS)
    T = max(1.5 * (t63 - t28), 1e-3 * ts)
    L = max(t63 - T, 0.0)
    return K, L, T


def step_models(model, transform: np.ndarray | None = None) -> StepModel:
    """Three-parameter model of each diagonal channel of $G W$ (W = `transform`, default I)."""
    ss = as_state_space(model)
    A, B, C, D = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    if transform is not None:
        B, D = B @ transform, D @ transform
    G0 = C @ np.linalg.solve(np.eye(A.shape[0]) - A, B) + D
    # `fit_step_model` with K = G0[i, i] reads a response up to its first sample >= 0.632 K
    # (the later crossing): the samples after it, most of the horizon, are not computed
    S = step_responses(A, B, C, D, step_horizon(ss), until=FIT_LEVELS[-1] * np.diag(G0))
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
# interaction analysis, decoupling and invertibility
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
    lam = rga(np.asarray(as_state_space(model).dcgain()))
    off = lam - np.diag(np.diag(lam))
    return bool(np.max(np.abs(np.diag(lam) - 1.0)) > tol or np.max(np.abs(off)) > tol)


def decoupling_matrix(model, kind: str = "CB") -> np.ndarray:
    """Static decoupler $W_1$: `"CB"` gives $(CB)^{-1}$ (thesis eq. 2.14), `"G0"` gives
    $G(0)^{-1}$ (eq. 2.13)."""
    ss = as_state_space(model)
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
    ss = as_state_space(model)
    A, B, C = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C))
    CB = C @ B
    if np.linalg.cond(CB) > 1e10:
        return False
    Z = A - B @ np.linalg.solve(CB, C @ A)
    ev = np.linalg.eigvals(Z)
    return bool(np.all(np.isfinite(ev)) and np.max(np.abs(ev)) < 1.0 - margin)
