"""A smooth, differentiable peak sensitivity of PI-family loops, for a penalty inside the
tuning cost (robustness constrained in tuning, not only checked after it).

On a fixed grid $\\omega_1..\\omega_F$ up to Nyquist, with the design model's response
$G_f = C (e^{j\\omega_f} I - A)^{-1} B + D$ computed once and the PI law
$K(z) = -(K_p + \\phi(z) K_i)$, $\\phi = z/(z - 1)$ (backward Euler) or
$\\tfrac12 (z + 1)/(z - 1)$ (Tustin), as `control.margins.peak_sensitivity` uses:

$$\\tilde M_s = t \\log \\sum_f e^{\\bar\\sigma(S_f)/t}, \\qquad S_f = (I - G_f K(e^{j\\omega_f}))^{-1},$$

a soft maximum over the grid ($\\max_f \\bar\\sigma \\le \\tilde M_s \\le \\max_f \\bar\\sigma +
t \\log F$), differentiable in $K_p$, $K_i$ through the singular values. The penalty added to
the tuning objective is $\\mu\\, \\max(0, \\tilde M_s - M)^2$: zero inside the limit, smooth
(C¹) for a quasi-Newton search. Stability is not part of $\\tilde M_s$: the tuning guard's
eigenvalue check (`training.loop_ms`) still decides.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..control.mimo_pi import MIMOPI
from ..control.pi import DiagonalPI
from ..control.rules import as_state_space
from ..control.schedule_ff import ScheduleFF


def pi_law(ctrl) -> tuple[Array, Array, bool] | None:
    """`(Kp, Ki, tustin)` as JAX arrays (differentiable in the controller's leaves) of a
    `DiagonalPI`, a `MIMOPI` or a `ScheduleFF` around one; None for other families."""
    if isinstance(ctrl, ScheduleFF):
        ctrl = ctrl.feedback
    if isinstance(ctrl, MIMOPI):
        kp, ki = ctrl.gains()
        return kp, ki, False
    if isinstance(ctrl, DiagonalPI):
        return jnp.diag(ctrl.kp), jnp.diag(ctrl.kp * ctrl.ts / ctrl.ti), ctrl.method == "tustin"
    return None


def model_response(model, n_freq: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """`(z, G)`: `n_freq` log-spaced points $e^{j\\omega}$, $\\omega \\in [10^{-4}, \\pi]$, and
    the model's frequency response `(F, ny, nu)` there (computed once, constant in tuning)."""
    ss = as_state_space(model)
    A, B, C, D = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    z = np.exp(1j * np.logspace(-4, np.log10(np.pi), int(n_freq)))
    eye = np.eye(A.shape[0])
    return z, np.stack([C @ np.linalg.solve(zk * eye - A, B) + D for zk in z])


def soft_peak_sensitivity(ctrl, z, G, t: float = 0.01) -> Float[Array, ""] | None:
    """$\\tilde M_s$ (module docstring) of `ctrl` on the response `G` at the points `z`
    (`model_response`), `t` the softness; None for a family without a PI law here."""
    law = pi_law(ctrl)
    if law is None:
        return None
    kp, ki, tustin = law
    z = jnp.asarray(z)
    phi = 0.5 * (z + 1) / (z - 1) if tustin else z / (z - 1)
    K = -(kp[None] + phi[:, None, None] * ki[None])
    eye = jnp.eye(G.shape[1], dtype=K.dtype)
    S = jnp.linalg.inv(eye[None] - jnp.asarray(G) @ K)
    sig = jnp.linalg.svd(S, compute_uv=False)[:, 0]
    return t * jax.nn.logsumexp(sig / t)


def ms_penalty(ctrl, z, G, ms_max: float, weight: float) -> Float[Array, ""]:
    """$\\mu \\max(0, \\tilde M_s - M)^2$ with $\\mu$ = `weight`, $M$ = `ms_max` (0 for a
    family without a PI law)."""
    ms = soft_peak_sensitivity(ctrl, z, G)
    if ms is None:
        return jnp.zeros(())
    return weight * jnp.maximum(ms - ms_max, 0.0) ** 2
