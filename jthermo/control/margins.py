"""Peak sensitivity of a feedback loop on a linear model (robustness reported, not assumed).

$$M_s = \\max_\\omega \\bar\\sigma\\big(S(e^{j\\omega T_s})\\big), \\qquad
S = (I - G K_{yu})^{-1},$$

with $G(z) = C (zI - A)^{-1} B + D$ the model and $K_{yu}(z)$ the controller's transfer from
the measurement to the input, saturation left out (Skogestad & Postlethwaite 2005, §2.4.3:
$M_s \\le 2$ guarantees a gain margin ≥ 2 and a phase margin ≥ 29°). Feed-forward paths (set
point, schedule) do not enter $S$: a `ScheduleFF` is judged by its feedback controller.
"""

from __future__ import annotations

import numpy as np

from ..errors import ControlError
from .decoupled import DecoupledPI
from .feedforward import FeedForward
from .lqg import LQG, compiled_gains
from .mimo_pi import MIMOPI
from .pi import DiagonalPI
from .rules import as_state_space
from .schedule_ff import ScheduleFF


def _pi_matrices(ctrl):
    """`(Kp, Ki, tustin)` of the PI laws: $u = K_p e + I$, $I_k = I_{k-1} + K_i e_k$."""
    if isinstance(ctrl, MIMOPI):
        kp, ki = (np.asarray(g, np.float64) for g in ctrl.gains())
        return kp, ki, False
    if isinstance(ctrl, (DiagonalPI, FeedForward)):
        kp, ti = np.asarray(ctrl.kp, np.float64), np.asarray(ctrl.ti, np.float64)
        tustin = isinstance(ctrl, DiagonalPI) and ctrl.method == "tustin"
        return np.diag(kp), np.diag(kp * ctrl.ts / ti), tustin
    if isinstance(ctrl, DecoupledPI):
        kp, ti = np.asarray(ctrl.kp, np.float64), np.asarray(ctrl.ti, np.float64)
        W1 = np.eye(kp.shape[0]) if ctrl.W1 is None else np.asarray(ctrl.W1, np.float64)
        return W1 * kp[None, :], W1 * (kp * ctrl.ts / ti)[None, :], False
    return None


def _lqg_state_space(ctrl: LQG):
    """$(A_c, B_c, C_c, D_c)$ from y (deviation) to u (deviation) of the LQG with integrators."""
    g = compiled_gains(ctrl)
    A, B, C = (np.asarray(m, np.float64) for m in (ctrl.A, ctrl.B, ctrl.C))
    Lx, Li, M = (np.asarray(m, np.float64) for m in (g.Lx, g.Li, g.M))
    nx, ny = A.shape[0], C.shape[0]
    F = np.eye(nx) - M @ C                      # x_f = F x + M y
    Cc = np.concatenate([-Lx @ F, -Li], axis=1)
    Dc = -Lx @ M
    Ac = np.block([[A @ F + B @ Cc[:, :nx], B @ Cc[:, nx:]],
                   [np.zeros((ny, nx)), np.eye(ny)]])
    Bc = np.concatenate([A @ M + B @ Dc, -ctrl.ts * np.eye(ny)], axis=0)
    return Ac, Bc, Cc, Dc


def controller_response(ctrl, z: np.ndarray) -> np.ndarray:
    """$K_{yu}(z)$ `(F, nu, ny)` at the complex points `z` `(F,)`; `ControlError` for a
    controller with no linear feedback form here (IMC, gated)."""
    if isinstance(ctrl, ScheduleFF):
        ctrl = ctrl.feedback
    pi = _pi_matrices(ctrl)
    if pi is not None:
        kp, ki, tustin = pi
        f = 0.5 * (z + 1) / (z - 1) if tustin else z / (z - 1)
        return -(kp[None] + f[:, None, None] * ki[None])
    if isinstance(ctrl, LQG):
        Ac, Bc, Cc, Dc = _lqg_state_space(ctrl)
        eye = np.eye(Ac.shape[0])
        return np.stack([Cc @ np.linalg.solve(zk * eye - Ac, Bc) + Dc for zk in z])
    raise ControlError(f"peak_sensitivity: no linear feedback form for {type(ctrl).__name__}")


def peak_sensitivity(model, ctrl, n_freq: int = 600) -> dict:
    """$M_s$ of `ctrl` on the linear `model` (any `AbstractModel`; e.g. `tune.printer_model`),
    on `n_freq` log-spaced frequencies up to Nyquist, and whether the loop is stable (all
    closed-loop poles inside the unit circle, checked by the eigenvalues of the loop).

    **Returns:** `{"ms": float, "frequency_hz": where, "stable": bool}`.
    """
    ss = as_state_space(model)
    A, B, C, D = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    w = np.logspace(-4, np.log10(np.pi), int(n_freq))
    z = np.exp(1j * w)
    K = controller_response(ctrl, z)
    eye = np.eye(A.shape[0])
    G = np.stack([C @ np.linalg.solve(zk * eye - A, B) + D for zk in z])
    S = np.linalg.inv(np.eye(C.shape[0])[None] - G @ K)
    sig = np.linalg.svd(S, compute_uv=False)[:, 0]
    i = int(np.argmax(sig))
    return {"ms": float(sig[i]), "frequency_hz": float(w[i] / (2 * np.pi * ss.ts)),
            "stable": _closed_loop_stable(A, B, C, D, ctrl)}


def _closed_loop_stable(A, B, C, D, ctrl) -> bool:
    """Closed-loop poles from the loop's state space (plant ⊕ controller)."""
    if isinstance(ctrl, ScheduleFF):
        ctrl = ctrl.feedback
    pi = _pi_matrices(ctrl)
    if pi is not None:
        kp, ki, tustin = pi
        # state q_k = I_{k-1}: q_{k+1} = q_k - K_i y_k, u_k = q_k - (K_p + c K_i) y_k, with
        # c = 1 (Euler backward) or 1/2 (Tustin: I_k = I_{k-1} + K_i (e_k + e_{k-1}) / 2)
        n = kp.shape[0]
        Ac, Bc, Cc, Dc = np.eye(n), -ki, np.eye(n), -(kp + (0.5 if tustin else 1.0) * ki)
    else:
        Ac, Bc, Cc, Dc = _lqg_state_space(ctrl)
    if np.any(D):
        raise ControlError("peak_sensitivity: the stability check needs a strictly proper model")
    top = np.concatenate([A + B @ Dc @ C, B @ Cc], axis=1)
    bot = np.concatenate([Bc @ C, Ac], axis=1)
    return bool(np.max(np.abs(np.linalg.eigvals(np.concatenate([top, bot], axis=0)))) < 1.0)
