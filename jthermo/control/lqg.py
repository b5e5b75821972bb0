"""State feedback from a Kalman observer, with integral action and a static gain L0
(thesis §2.2.6, Fig. 2.4), designed by LQG from discrete Riccati equations solved in JAX.

The Riccati equations are solved by the structure-preserving doubling algorithm, a fixed
number of iterations of plain linear algebra, so `jax.grad` reaches the weights Q1, Q2 through
the solution (Chu et al. 2004, "Structure-preserving algorithms for periodic discrete-time
algebraic Riccati equations"; Anderson & Moore 1979 for LQG).

Design model: the model's $(A, B, C)$ augmented with integrators of the tracking error,
$\\xi_{k+1} = \\xi_k + T_s (r_k - y_k)$. The LQ cost $\\sum y^T Q_1 y + \\xi^T Q_i \\xi +
u^T Q_2 u$ gives $u = u_0 + L_0 (r - y_0) - L_x \\hat x - L_i \\xi$ with
$L_0 = [C (I - A + B L_x)^{-1} B]^{-1}$ (unit static gain without the integrator). The
observer is the steady-state Kalman filter for process noise $q_w I$ and measurement noise
$I$, fed with the saturated input. Anti-windup: an integrator holds while its input channel is
saturated in the direction its error pushes.

Second degree of freedom (set-point weighting against a reference model; Åström & Hägglund
2006, §3.4): a first-order reference model $r^m_{k+1} = r^m_k + (1 - e^{-T_s/\\tau_r})
(r_k - r^m_k)$, started at the first measurement (the plant is taken at steady state there, as
by the observer), gives the lag $\\delta = r - r^m$ of the reference behind its model, and the
static path sees $r - b_0 \\delta$ instead of $r$. The weight starts at 0 (the classical
design); the lag vanishes in steady state and under a constant set point that the plant
already sits at, so the handle shapes the response to set-point changes (when the heaters
come off full power, the overshoot) and leaves disturbance rejection to the LQG feedback.
The integrators keep the plain error $r - y$: weighting their input too slows the removal of
a steady-state mismatch on a plant other than the design model.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._types import Input, Output, Setpoint
from ..errors import ControlError
from ._base import U_MAX, U_MIN, AbstractController
from .rules import as_array, as_state_space

sg = jax.lax.stop_gradient


def _fori(xp, iters, body, carry):
    """`iters` applications of `body(i, carry)`: a `lax.fori_loop` (traceable, differentiable)
    for `jnp`, a Python loop for NumPy (no compile)."""
    if xp is np:
        for i in range(iters):
            carry = body(i, carry)
        return carry
    return jax.lax.fori_loop(0, iters, body, carry)


def solve_dare(A: Float[Array, "n n"], B: Float[Array, "n m"], Q: Float[Array, "n n"],
               R: Float[Array, "m m"], iters: int = 40, *, xp=jnp) -> Float[Array, "n n"]:
    """Stabilising solution X of $X = A^T X A - A^T X B (R + B^T X B)^{-1} B^T X A + Q$.

    Structure-preserving doubling: $A_0 = A$, $G_0 = B R^{-1} B^T$, $H_0 = Q$,
    $W = I + G_k H_k$, $A_{k+1} = A_k W^{-1} A_k$, $G_{k+1} = G_k + A_k W^{-1} G_k A_k^T$,
    $H_{k+1} = H_k + A_k^T H_k W^{-1} A_k \\to X$ (quadratic convergence; 40 doublings cover a
    horizon of $2^{40}$ samples). Differentiable: a `lax.fori_loop` of fixed length. `xp`:
    `jnp` (default) or `np`, the same iterations in NumPy float64 where nothing is
    differentiated (a design check: no program to compile).
    """
    n = A.shape[0]
    eye = xp.eye(n, dtype=A.dtype)
    G0 = B @ xp.linalg.solve(R, B.T)
    G0 = 0.5 * (G0 + G0.T)

    def body(_, carry):
        Ak, Gk, Hk = carry
        W = eye + Gk @ Hk
        WiA = xp.linalg.solve(W, Ak)                   # W^{-1} A_k
        WiG = xp.linalg.solve(W, Gk)                   # W^{-1} G_k
        A1 = Ak @ WiA
        G1 = Gk + Ak @ WiG @ Ak.T
        H1 = Hk + Ak.T @ Hk @ WiA
        return A1, 0.5 * (G1 + G1.T), 0.5 * (H1 + H1.T)

    _, _, X = _fori(xp, iters, body, (A, G0, Q))
    return X


def lqr_gain(A, B, Q, R, iters: int = 40, *, xp=jnp):
    """Discrete LQR gain $L = (R + B^T X B)^{-1} B^T X A$ and X (`xp`: as `solve_dare`)."""
    X = solve_dare(A, B, Q, R, iters, xp=xp)
    return xp.linalg.solve(R + B.T @ X @ B, B.T @ X @ A), X


def lqg_gains(A, B, C, q1, q2, qi, qw, ts: float, iters: int = 40, *, xp=jnp) -> "LQGGains":
    """`LQGGains` of the design model $(A, B, C)$ and the diagonal weights (`LQG.gains`), in
    `xp` = `jnp` (traceable) or `np` (float64, eager, nothing compiled)."""
    nx, ny = A.shape[0], C.shape[0]
    dt = A.dtype
    Aa = xp.block([[A, xp.zeros((nx, ny), dt)], [-ts * C, xp.eye(ny, dtype=dt)]])
    Ba = xp.concatenate([B, xp.zeros((ny, B.shape[1]), dt)], axis=0)
    Qx = C.T @ (q1[:, None] * C) + 1e-9 * xp.eye(nx, dtype=dt)
    Qa = xp.block([[Qx, xp.zeros((nx, ny), dt)], [xp.zeros((ny, nx), dt), xp.diag(qi)]])
    La, _ = lqr_gain(Aa, Ba, Qa, xp.diag(q2), iters, xp=xp)
    Lx, Li = La[:, :nx], La[:, nx:]
    L0 = xp.linalg.inv(C @ xp.linalg.solve(xp.eye(nx, dtype=dt) - A + B @ Lx, B))
    P = solve_dare(A.T, C.T, qw * xp.eye(nx, dtype=dt), xp.eye(ny, dtype=dt), iters, xp=xp)
    M = P @ C.T @ xp.linalg.inv(C @ P @ C.T + xp.eye(ny, dtype=dt))
    return LQGGains(Lx=Lx, Li=Li, L0=L0, M=M)


class LQGGains(eqx.Module):
    Lx: Float[Array, "nu nx"]
    Li: Float[Array, "nu ny"]
    L0: Float[Array, "nu ny"]
    M: Float[Array, "nx ny"]       # Kalman measurement-update gain P C^T (C P C^T + I)^-1


class LQGState(eqx.Module):
    x: Float[Array, " nx"]         # predicted state x̂(k|k-1)
    xi: Float[Array, " ny"]        # tracking-error integrators, °C·s
    rm: Float[Array, " ny"]        # reference-model output, °C
    gains: LQGGains                # computed once per rollout in `init` (from Q1, Q2, qw)


class LQG(AbstractController):
    """LQG with integral action; tunable leaves: the (positive) diagonal weights and the
    set-point weight `b0` with the reference-model time constant `tau_r`."""

    q1: Float[Array, " ny"]        # output weight, 1/°C², tunable
    q2: Float[Array, " nu"]        # input weight, tunable
    qi: Float[Array, " ny"]        # integrator weight, tunable
    qw: Float[Array, ""]           # process-noise intensity relative to measurement noise
    b0: Float[Array, " ny"]        # set-point weight on the model lag, static path (0: classical)
    tau_r: Float[Array, " ny"]     # reference-model time constant, s (positive)
    A: Float[Array, "nx nx"]       # design model (fixed)
    B: Float[Array, "nx nu"]
    C: Float[Array, "ny nx"]
    u_op: Float[Array, " nu"]
    y_op: Float[Array, " ny"]
    ts: float = eqx.field(static=True)
    iters: int = eqx.field(static=True, default=40)

    def gains(self) -> LQGGains:
        """Feedback, integral, static and observer gains from the current weights."""
        return lqg_gains(sg(self.A), sg(self.B), sg(self.C), self.q1, self.q2, self.qi,
                         self.qw, self.ts, self.iters)

    def init(self, y0: Output, r0: Setpoint) -> LQGState:
        g = self.gains()
        A, B = sg(self.A), sg(self.B)
        nx = A.shape[0]
        # start in the steady state that produces y0 under the static feed-through
        u_ss = g.L0 @ (y0 - sg(self.y_op))
        x0 = jnp.linalg.solve(jnp.eye(nx, dtype=A.dtype) - A + B @ g.Lx, B @ u_ss)
        # the reference model starts where the plant is: no lag until the set point moves
        rm = y0 + jnp.zeros_like(self.tau_r)
        return LQGState(x=x0, xi=jnp.zeros_like(y0 * self.q1), rm=rm, gains=g)

    def step(self, state: LQGState, y: Output, r: Setpoint) -> tuple[Input, LQGState]:
        return self.step_offset(state, y, r, 0.0)

    def step_offset(self, state: LQGState, y: Output, r: Setpoint,
                    u_add) -> tuple[Input, LQGState]:
        """One sample with an additive input `u_add` (a schedule feed-forward) inside the
        saturation; the observer is fed the applied (saturated) input, `u_add` included."""
        g = state.gains
        A, B, C = sg(self.A), sg(self.B), sg(self.C)
        x_f = state.x + g.M @ (y - sg(self.y_op) - C @ state.x)
        lag = r - state.rm                       # reference ahead of its model, °C
        e = r - y
        u_req = (self.u_op + u_add + g.L0 @ (r - self.b0 * lag - sg(self.y_op)) - g.Lx @ x_f
                 - g.Li @ state.xi)
        u = jnp.clip(u_req, U_MIN, U_MAX)
        hold = ((u_req > U_MAX) & (e > 0)) | ((u_req < U_MIN) & (e < 0))
        xi = jnp.where(hold, state.xi, state.xi + self.ts * e)
        x_next = A @ x_f + B @ (u - self.u_op)
        rm = state.rm + (1.0 - jnp.exp(-self.ts / self.tau_r)) * lag
        return u, LQGState(x=x_next, xi=xi, rm=rm, gains=g)


def compiled_gains(ctrl: LQG) -> LQGGains:
    """`ctrl.gains()` for use outside jit, as NumPy float64 arrays: the same doubling
    iterations (`lqg_gains(xp=np)`) run eagerly on the small dense matrices, so nothing is
    compiled (as one compiled program it cost a compile per state size; eager JAX compiled
    about 50 small programs)."""
    f = lambda a: np.asarray(a, np.float64)
    return lqg_gains(f(ctrl.A), f(ctrl.B), f(ctrl.C), f(ctrl.q1), f(ctrl.q2), f(ctrl.qi),
                     f(ctrl.qw), ctrl.ts, ctrl.iters, xp=np)


def design_lqg(model, Q1=1.0, Q2=1.0, *, Qi=0.01, qw=0.1, tau_r=10.0,
               iters: int = 40) -> LQG:
    """LQG with integral action from a model.

    **Arguments:**
    - `Q1`: weight on the output deviation (1/°C²), scalar or per output.
    - `Q2`: weight on the input (per unit power fraction squared), scalar or per input.
    - `Qi`: weight on the error integrators, scalar or per output.
    - `qw`: process-noise intensity of the Kalman observer relative to unit measurement noise.
    - `tau_r`: time constant of the reference model (s), scalar or per output; the set-point
      weight on its lag starts at 0, so it only matters once that is tuned.
    """
    ss = as_state_space(model)
    ny, nu = ss.C.shape[0], ss.B.shape[1]

    def vec(v, n, name):
        a = np.broadcast_to(np.asarray(v, np.float64), (n,)).copy() if np.ndim(v) <= 1 \
            else np.diag(np.asarray(v, np.float64)).copy()
        if a.shape != (n,) or np.any(~np.isfinite(a)) or np.any(a <= 0):
            raise ControlError(f"design_lqg: {name} must be positive with {n} entries, got {v}")
        return a

    q1, q2, qi = vec(Q1, ny, "Q1"), vec(Q2, nu, "Q2"), vec(Qi, ny, "Qi")
    tau = vec(tau_r, ny, "tau_r")
    if not np.isfinite(qw) or qw <= 0:
        raise ControlError(f"design_lqg: qw must be positive, got {qw}")
    f = as_array
    ctrl = LQG(q1=f(q1), q2=f(q2), qi=f(qi), qw=f(qw), b0=f(np.zeros(ny)), tau_r=f(tau),
               A=f(ss.A), B=f(ss.B), C=f(ss.C), u_op=f(ss.u0), y_op=f(ss.y0), ts=ss.ts,
               iters=iters)
    g = compiled_gains(ctrl)
    if not all(np.all(np.isfinite(np.asarray(leaf))) for leaf in jax.tree_util.tree_leaves(g)):
        raise ControlError("design_lqg: the Riccati solution is not finite for these weights")
    return ctrl
