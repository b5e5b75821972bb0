"""The interface every model family shares, and the innovations state space they all convert to.

Every model is a discrete-time system with sample time `ts` (s), `nu` manipulated inputs
(heater power fractions), `nw` measured external signals (e.g. the surroundings' temperature,
°C) and `ny` outputs (°C). Absolute units are kept: models carry an operating point
(`u0`, `w0`, `y0`) so that `simulate(u)` returns temperatures in °C directly.

Innovations form (Ljung 1999, §4.3), with deviations $\\tilde u = u - u_0$, $\\tilde w = w - w_0$:

$$x_{k+1} = A x_k + B \\tilde u_k + B_w \\tilde w_k + K e_k, \\qquad
  y_k = y_0 + C x_k + D \\tilde u_k + e_k.$$
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._types import Disturbance, Input, Output, State
from ..errors import ModelError


def _zeros_if_none(w, T, nw, dtype):
    if w is None:
        return jnp.zeros((T, nw), dtype)
    return jnp.asarray(w, dtype)


class AbstractModel(eqx.Module):
    """A discrete-time model of a multi-zone thermal system.

    Subclasses implement `to_statespace` (exact for linear families) and may override
    `step`/`output`/`simulate`/`predict` with faster or nonlinear versions. The defaults
    below go through the state space, so a new linear family only needs `to_statespace`.
    """

    @abc.abstractmethod
    def to_statespace(self) -> "StateSpace":
        """The model as an innovations state space (A, B, Bw, C, D, K) with its operating point."""

    def __repr__(self) -> str:
        """Inputs, outputs, Ts, DC gain and poles (`models.summary.describe`)."""
        from .summary import describe

        return describe(self)

    # -- sizes -----------------------------------------------------------------------
    @property
    def ts(self) -> float:
        return self.to_statespace().ts

    @property
    def n_inputs(self) -> int:
        return self.to_statespace().B.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.to_statespace().C.shape[0]

    @property
    def n_signals(self) -> int:
        """Number of measured external signals `w` the model uses."""
        return self.to_statespace().Bw.shape[1]

    @property
    def n_states(self) -> int:
        return self.to_statespace().A.shape[0]

    # -- plant interface used by the closed-loop simulator ----------------------------
    def initial_state(self, y0: Output | None = None) -> State:
        """A state consistent with output `y0` in steady state at the operating point
        (least squares on $C x = y_0 - y_{op}$); zeros when `y0` is None."""
        return self.to_statespace().initial_state(y0)

    def step(self, x: State, u: Input, w: Disturbance | None = None) -> State:
        """$x_{k+1} = A x_k + B (u_k - u_0) + B_w (w_k - w_0)$ (no innovation)."""
        return self.to_statespace().step(x, u, w)

    def output(self, x: State) -> Output:
        """$y_k = y_0 + C x_k$ (the closed loop needs a strictly proper plant: D is ignored)."""
        return self.to_statespace().output(x)

    # -- simulation and prediction -----------------------------------------------------
    def simulate(self, u: Float[Array, "T nu"], w: Float[Array, "T nw"] | None = None,
                 x0: State | None = None) -> Float[Array, "T ny"]:
        """Simulated outputs from inputs alone (noise-free), starting from `x0` (default 0)."""
        return self.to_statespace().simulate(u, w, x0)

    def predict(self, y: Float[Array, "T ny"], u: Float[Array, "T nu"],
                w: Float[Array, "T nw"] | None = None, k: int = 1,
                x0: State | None = None) -> Float[Array, "T ny"]:
        """k-step-ahead predictions $\\hat y(t | t-k)$ (k = 1: the one-step predictor)."""
        return self.to_statespace().predict(y, u, w, k, x0)

    def residuals(self, y, u, w=None, x0=None) -> Float[Array, "T ny"]:
        """One-step prediction errors $\\varepsilon(t) = y(t) - \\hat y(t|t-1)$."""
        return jnp.asarray(y) - self.predict(y, u, w, 1, x0)

    # -- responses ----------------------------------------------------------------------
    def impulse_response(self, n: int) -> Float[Array, "n ny nu"]:
        """Markov parameters $g_0 = D$, $g_k = C A^{k-1} B$ for k = 0..n-1."""
        return self.to_statespace().impulse_response(n)

    def step_response(self, n: int) -> Float[Array, "n ny nu"]:
        """Deviation of y after a unit step on each input at k = 0 (cumulative impulse response)."""
        return jnp.cumsum(self.impulse_response(n), axis=0)

    def frequency_response(self, omega: Float[Array, " nf"]) -> Array:
        """$G(e^{i\\omega T_s})$ for angular frequencies `omega` in rad/s, shape `(nf, ny, nu)`."""
        return self.to_statespace().frequency_response(omega)

    def dcgain(self) -> Float[Array, "ny nu"]:
        """Steady-state gain $G(1) = C (I - A)^{-1} B + D$ in °C per unit input."""
        return self.to_statespace().dcgain()

    def poles(self) -> Array:
        return jnp.linalg.eigvals(self.to_statespace().A)


class StateSpace(AbstractModel):
    """Innovations state space, the common currency of all model families.

    Fields are arrays (fitted or tuned leaves); `ts` is static. `Bw` has zero columns when the
    model uses no measured signal; `K` is zero for an output-error model.
    """

    A: Float[Array, "nx nx"]
    B: Float[Array, "nx nu"]
    C: Float[Array, "ny nx"]
    D: Float[Array, "ny nu"]
    K: Float[Array, "nx ny"]
    Bw: Float[Array, "nx nw"]
    u0: Float[Array, " nu"]        # operating-point input (power fraction)
    w0: Float[Array, " nw"]        # operating-point measured signals
    y0: Float[Array, " ny"]        # operating-point output, °C
    ts_: float = eqx.field(static=True)

    def __init__(self, A, B, C, D=None, K=None, *, ts: float = 1.0, Bw=None, u0=None, w0=None,
                 y0=None):
        A = jnp.asarray(A)
        B = jnp.asarray(B)
        C = jnp.asarray(C)
        nx, nu, ny = A.shape[0], B.shape[1], C.shape[0]
        self.A, self.B, self.C = A, B, C
        self.D = jnp.zeros((ny, nu), A.dtype) if D is None else jnp.asarray(D)
        self.K = jnp.zeros((nx, ny), A.dtype) if K is None else jnp.asarray(K)
        self.Bw = jnp.zeros((nx, 0), A.dtype) if Bw is None else jnp.asarray(Bw)
        nw = self.Bw.shape[1]
        self.u0 = jnp.zeros(nu, A.dtype) if u0 is None else jnp.asarray(u0)
        self.w0 = jnp.zeros(nw, A.dtype) if w0 is None else jnp.asarray(w0)
        self.y0 = jnp.zeros(ny, A.dtype) if y0 is None else jnp.asarray(y0)
        self.ts_ = float(ts)

    def __check_init__(self):
        nx = self.A.shape[0]
        shapes = {"A": (self.A.shape, (nx, nx)), "B": (self.B.shape[0], nx),
                  "C": (self.C.shape[1], nx), "K": (self.K.shape, (nx, self.C.shape[0])),
                  "D": (self.D.shape, (self.C.shape[0], self.B.shape[1])), "Bw": (self.Bw.shape[0], nx)}
        for name, (got, want) in shapes.items():
            if got != want:
                raise ModelError(f"StateSpace: `{name}` has shape {got}, expected {want}")

    def to_statespace(self) -> "StateSpace":
        return self

    @property
    def ts(self) -> float:
        return self.ts_

    def initial_state(self, y0=None):
        nx = self.A.shape[0]
        if y0 is None:
            return jnp.zeros(nx, self.A.dtype)
        # steady state x = (I - A)^{-1} B du with C x = y0 - y_op: least squares on x directly
        return jnp.linalg.lstsq(self.C, jnp.asarray(y0) - self.y0)[0]

    def _wdev(self, w):
        if self.Bw.shape[1] == 0:
            return jnp.zeros((0,), self.A.dtype)
        return jnp.asarray(w) - self.w0

    def step(self, x, u, w=None):
        x_next = self.A @ x + self.B @ (u - self.u0)
        if self.Bw.shape[1]:
            if w is None:
                raise ModelError("StateSpace.step: this model needs the measured signals `w`")
            x_next = x_next + self.Bw @ (w - self.w0)
        return x_next

    def output(self, x):
        return self.y0 + self.C @ x

    def _inputs(self, u, w):
        u = jnp.asarray(u)
        if u.ndim == 1:
            u = u[:, None]
        T = u.shape[0]
        nw = self.Bw.shape[1]
        if nw and w is None:
            raise ModelError(f"this model needs {nw} measured signal(s) `w`")
        w = _zeros_if_none(w, T, nw, self.A.dtype) if nw else jnp.zeros((T, 0), self.A.dtype)
        if w.ndim == 1:
            w = w[:, None]
        return u - self.u0, w - self.w0 if nw else w

    def simulate(self, u, w=None, x0=None):
        du, dw = self._inputs(u, w)
        x0 = jnp.zeros(self.A.shape[0], self.A.dtype) if x0 is None else x0

        def body(x, inp):
            uk, wk = inp
            y = self.y0 + self.C @ x + self.D @ uk
            return self.A @ x + self.B @ uk + self.Bw @ wk, y

        _, ys = jax.lax.scan(body, x0, (du, dw))
        return ys

    def _filtered_states(self, y, du, dw, x0):
        """One-step predicted states $\\hat x(t|t-1)$ for t = 0..T-1 and the innovations."""
        x0 = jnp.zeros(self.A.shape[0], self.A.dtype) if x0 is None else x0

        def body(x, inp):
            yk, uk, wk = inp
            e = yk - self.y0 - self.C @ x - self.D @ uk
            return self.A @ x + self.B @ uk + self.Bw @ wk + self.K @ e, (x, e)

        _, (xs, es) = jax.lax.scan(body, x0, (jnp.asarray(y), du, dw))
        return xs, es

    def predict(self, y, u, w=None, k=1, x0=None):
        if k < 1:
            raise ModelError(f"predict: horizon k must be >= 1, got {k}")
        du, dw = self._inputs(u, w)
        xs, _ = self._filtered_states(y, du, dw, x0)
        T = xs.shape[0]
        # x̂(t|t-k): start from x̂(t-k+1|t-k) and propagate k-1 steps without innovations.
        # Z_0[t] = x̂(t-k+1|t-k);  Z_{j+1}[t] = A Z_j[t] + B ũ(t-k+1+j)  ->  Z_{k-1}[t] = x̂(t|t-k)
        X = jnp.roll(xs, k - 1, axis=0)
        for j in range(k - 1):   # k is a small static horizon
            U = jnp.roll(du, k - 1 - j, axis=0)
            W = jnp.roll(dw, k - 1 - j, axis=0)
            X = X @ self.A.T + U @ self.B.T + W @ self.Bw.T
        # the first k-1 samples have no k-step history: use the one-step predictions there
        if k > 1:
            X = jnp.where((jnp.arange(T) < k - 1)[:, None], xs, X)
        return self.y0 + X @ self.C.T + du @ self.D.T

    def impulse_response(self, n):
        def body(M, _):
            return self.A @ M, self.C @ M

        _, CAkB = jax.lax.scan(body, self.B, None, length=max(n - 1, 0))
        return jnp.concatenate([self.D[None], CAkB], axis=0)[:n]

    def frequency_response(self, omega):
        z = jnp.exp(1j * jnp.asarray(omega) * self.ts)
        eye = jnp.eye(self.A.shape[0])

        def one(zk):
            return self.C @ jnp.linalg.solve(zk * eye - self.A, self.B.astype(zk.dtype)) + self.D

        return jax.vmap(one)(z)

    def dcgain(self):
        eye = jnp.eye(self.A.shape[0], dtype=self.A.dtype)
        return self.C @ jnp.linalg.solve(eye - self.A, self.B) + self.D

    def dcgain_w(self):
        """Steady-state gain from the measured signals `w` to y."""
        eye = jnp.eye(self.A.shape[0], dtype=self.A.dtype)
        return self.C @ jnp.linalg.solve(eye - self.A, self.Bw)


def is_stable(model: AbstractModel, margin: float = 0.0) -> bool:
    """True if every pole lies strictly inside the circle of radius `1 - margin`."""
    return bool(jnp.max(jnp.abs(model.poles())) < 1.0 - margin)
