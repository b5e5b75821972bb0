"""The physical grey-box bed model (thesis eq. 3.5) and its extended whole-system variant.

Each bed zone $i$ is a heat capacity $C_i$ (J/K) that loses heat to the surroundings through a
conductance $G_i = 1/R_{s,i}$ (W/K) and receives heat from every heater $j$ with a gain $n_{ij}$
(W per unit power fraction):

$$\\dot T_i = -\\frac{G_i}{C_i}(T_i - T_s) + \\sum_j \\frac{n_{ij}}{C_i} u_j .$$

The state is the absolute zone temperature (°C), $y = T$, $u$ the heater power fractions and
the measured signal $w_0 = T_s$ (°C). The model is discretised exactly at the sample time `ts`
under a zero-order hold, $A_d = e^{A T_s}$, with a differentiable matrix exponential
(`jax.scipy.linalg.expm`). Every physical parameter is stored as its logarithm, so it is positive
by construction.

Identifiability: from temperatures only the ratios $G_i/C_i$ and $n_{ij}/C_i$ can be estimated;
the grey-box fit (`jthermo.identify.greybox.fit_greybox`) therefore keeps each capacity at a
nominal value (`capacity=`, default 1000 J/K) and fits the loss conductances and heater gains
relative to it.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ModelError
from ._base import AbstractModel, StateSpace

#: nominal heat capacity (J/K) used when fitting; only ratios to it are identifiable
NOMINAL_CAPACITY = 1000.0


def zoh(A: Float[Array, "n n"], B: Float[Array, "n m"], ts: float):
    """Exact zero-order-hold discretisation: $A_d = e^{A T_s}$, $B_d = \\int_0^{T_s} e^{A s} ds\\,B$.

    Uses the block matrix exponential of $[[A, B], [0, 0]] T_s$ (Van Loan 1978); differentiable.
    """
    n, m = A.shape[0], B.shape[1]
    M = jnp.zeros((n + m, n + m), A.dtype)
    M = M.at[:n, :n].set(A).at[:n, n:].set(B)
    E = jax.scipy.linalg.expm(M * ts)
    return E[:n, :n], E[:n, n:]


class BedModel(AbstractModel):
    """N-zone bed: isolated zones, a full heater-to-zone gain matrix, surroundings as input.

    **Fields** (all physical values stored as logarithms):
    - `log_capacity`: $\\log C_i$, J/K, `(N,)`.
    - `log_loss`: $\\log G_i = -\\log R_{s,i}$, W/K, `(N,)`.
    - `log_gain`: $\\log n_{ij}$, W, `(N, N)`: heater $j$ to zone $i$.
    - `innovation`: diagonal innovation gain `(N,)` (0 gives an output-error model).
    - `surroundings`: constant surroundings temperature in °C; when `measured_surroundings`
      is True it only names the nominal surroundings (`fit_greybox`: the estimation data's
      mean) at which controllers are designed (`nominal_point`).
    - `u_nominal`: nominal heater input `(heaters,)` (`fit_greybox`: the estimation data's
      mean; default 0, the bed at rest), the operating point of a design (`nominal_point`).
    - `ts`: sample time in s (static); `measured_surroundings` (static): True when
      $T_s$ is the measured signal `w[:, 0]`.

    With `measured_surroundings=True` the state space has states = absolute zone temperatures,
    `Bw` one column and u0 = w0 = y0 = 0. With False it has no measured signal, its state is the
    temperature above `surroundings`, and `y0 = surroundings`.
    """

    log_capacity: Float[Array, " zones"]
    log_loss: Float[Array, " zones"]
    log_gain: Float[Array, "zones heaters"]
    innovation: Float[Array, " zones"]
    surroundings: Float[Array, ""]
    u_nominal: Float[Array, " heaters"]
    ts_: float = eqx.field(static=True)
    measured_surroundings: bool = eqx.field(static=True)

    def __init__(self, log_capacity, log_loss, log_gain, *, innovation=None, surroundings=20.0,
                 u_nominal=None, ts: float = 1.0, measured_surroundings: bool = True):
        self.log_capacity = jnp.asarray(log_capacity)
        self.log_loss = jnp.asarray(log_loss)
        self.log_gain = jnp.asarray(log_gain)
        n = self.log_capacity.shape[0] if self.log_capacity.ndim else 0
        self.innovation = (jnp.zeros(n, self.log_capacity.dtype) if innovation is None
                           else jnp.asarray(innovation))
        self.surroundings = jnp.asarray(surroundings, self.log_capacity.dtype)
        nu = self.log_gain.shape[-1] if self.log_gain.ndim == 2 else 0
        self.u_nominal = jnp.broadcast_to(jnp.asarray(
            0.0 if u_nominal is None else u_nominal, self.log_capacity.dtype), (nu,))
        self.ts_ = float(ts)
        self.measured_surroundings = bool(measured_surroundings)

    def __check_init__(self):
        n = self.log_capacity.shape[0] if self.log_capacity.ndim == 1 else -1
        if n < 1:
            raise ModelError("BedModel: `capacity` must be a non-empty 1-D array")
        if self.log_loss.shape != (n,):
            raise ModelError(f"BedModel: `loss` has shape {self.log_loss.shape}, expected ({n},)")
        if self.log_gain.ndim != 2 or self.log_gain.shape[0] != n:
            raise ModelError(f"BedModel: `gain` has shape {self.log_gain.shape}, expected ({n}, heaters)")
        if self.innovation.shape != (n,):
            raise ModelError(f"BedModel: `innovation` has shape {self.innovation.shape}, expected ({n},)")
        if not self.ts_ > 0:
            raise ModelError(f"BedModel: sample time must be positive, got {self.ts_}")

    @classmethod
    def from_physical(cls, capacity, loss, gain, ts: float = 1.0, *, innovation=None,
                      surroundings=20.0, measured_surroundings: bool = True) -> BedModel:
        """Build from physical values: `capacity` $C_i$ (J/K, `(N,)`), `loss` $G_i$ (W/K, `(N,)`),
        `gain` $n_{ij}$ (W, `(N, N)`, heater j to zone i), all strictly positive."""
        vals = {}
        for name, v in (("capacity", capacity), ("loss", loss), ("gain", gain)):
            a = np.asarray(v, dtype=np.float64)
            if not np.all(np.isfinite(a)) or np.any(a <= 0):
                raise ModelError(f"BedModel.from_physical: `{name}` must be finite and > 0")
            vals[name] = jnp.log(jnp.asarray(a))
        return cls(vals["capacity"], vals["loss"], vals["gain"], innovation=innovation,
                   surroundings=surroundings, ts=ts, measured_surroundings=measured_surroundings)

    # -- physical values ------------------------------------------------------------------
    @property
    def capacity(self):
        return jnp.exp(self.log_capacity)

    @property
    def loss(self):
        return jnp.exp(self.log_loss)

    @property
    def gain(self):
        return jnp.exp(self.log_gain)

    @property
    def ts(self) -> float:
        return self.ts_

    def continuous(self):
        """Continuous-time matrices $(A, B, B_w)$ of eq. 3.5 (1/s, K/s per unit, 1/s)."""
        c = self.capacity
        a = self.loss / c
        return -jnp.diag(a), self.gain / c[:, None], a[:, None]

    def time_constants(self):
        """Zone time constants $C_i/G_i$ in s."""
        return self.capacity / self.loss

    def nominal_point(self):
        """`(inputs, signals)` at which a controller is designed (`control.design.design_point`):
        `u_nominal` and, when the surroundings are measured, `[surroundings]` (else None)."""
        w = jnp.reshape(self.surroundings, (1,)) if self.measured_surroundings else None
        return self.u_nominal, w

    def to_statespace(self) -> StateSpace:
        A, B, Bw = self.continuous()
        n, nu = B.shape
        Ad, BB = zoh(A, jnp.concatenate([B, Bw], axis=1), self.ts_)
        K = jnp.diag(self.innovation)
        if self.measured_surroundings:
            return StateSpace(Ad, BB[:, :nu], jnp.eye(n, dtype=Ad.dtype), K=K, ts=self.ts_,
                              Bw=BB[:, nu:])
        return StateSpace(Ad, BB[:, :nu], jnp.eye(n, dtype=Ad.dtype), K=K, ts=self.ts_,
                          y0=jnp.full((n,), self.surroundings, Ad.dtype))


class ExtendedBedModel(AbstractModel):
    """Whole-system thermal network: bed zones plus extra bodies (walls, build plate, powder
    container) as extra nodes, conductive couplings along `edges`, heaters on any node and
    sensors on any node.

    $$C_k \\dot T_k = -G_k (T_k - T_s) - \\sum_{(k,l)\\in E} g_{kl}(T_k - T_l) + \\sum_j n_{kj} u_j$$

    **Fields:** `log_capacity (M,)` J/K, `log_loss (M,)` W/K, `log_coupling (E,)` W/K,
    `log_gain (M, nu)` W; static `edges` (pairs of node indices), `sensors` (node index of each
    output), `ts`. The surroundings temperature is the measured signal `w[:, 0]`; states are
    absolute node temperatures in °C.
    """

    log_capacity: Float[Array, " nodes"]
    log_loss: Float[Array, " nodes"]
    log_coupling: Float[Array, " edges"]
    log_gain: Float[Array, "nodes heaters"]
    edges: tuple[tuple[int, int], ...] = eqx.field(static=True)
    sensors: tuple[int, ...] = eqx.field(static=True)
    ts_: float = eqx.field(static=True)

    def __init__(self, log_capacity, log_loss, log_coupling, log_gain, *, edges, sensors,
                 ts: float = 1.0):
        self.log_capacity = jnp.asarray(log_capacity)
        self.log_loss = jnp.asarray(log_loss)
        self.log_coupling = jnp.asarray(log_coupling)
        self.log_gain = jnp.asarray(log_gain)
        self.edges = tuple((int(a), int(b)) for a, b in edges)
        self.sensors = tuple(int(s) for s in sensors)
        self.ts_ = float(ts)

    def __check_init__(self):
        m = self.log_capacity.shape[0]
        if self.log_loss.shape != (m,) or self.log_gain.ndim != 2 or self.log_gain.shape[0] != m:
            raise ModelError("ExtendedBedModel: `loss` and `gain` must have one row per node")
        if len(self.edges) != self.log_coupling.shape[0]:
            raise ModelError("ExtendedBedModel(edges=...) does not match `coupling`")
        for a, b in self.edges:
            if not (0 <= a < m and 0 <= b < m) or a == b:
                raise ModelError(f"ExtendedBedModel: edge ({a}, {b}) is not a pair of distinct nodes")
        if not self.sensors or any(not 0 <= s < m for s in self.sensors):
            raise ModelError(f"ExtendedBedModel: sensors {self.sensors} must index the {m} nodes")

    @classmethod
    def from_physical(cls, capacity, loss, gain, *, coupling=(), edges=(), sensors=None,
                      ts: float = 1.0) -> ExtendedBedModel:
        """Physical values: `capacity (M,)` J/K, `loss (M,)` W/K, `gain (M, nu)` W (zeros
        allowed: a body without heater), `coupling (E,)` W/K along `edges`; `sensors` defaults
        to the first `nu` nodes (the bed zones)."""
        gain = np.asarray(gain, dtype=np.float64)
        for name, v in (("capacity", capacity), ("loss", loss), ("coupling", coupling)):
            a = np.asarray(v, dtype=np.float64)
            if not np.all(np.isfinite(a)) or np.any(a <= 0):
                raise ModelError(f"ExtendedBedModel.from_physical: `{name}` must be finite and > 0")
        if not np.all(np.isfinite(gain)) or np.any(gain < 0):
            raise ModelError("ExtendedBedModel.from_physical: `gain` must be finite and >= 0")
        sensors = tuple(range(gain.shape[1])) if sensors is None else sensors
        with np.errstate(divide="ignore"):
            lg = np.where(gain > 0, np.log(np.where(gain > 0, gain, 1.0)), -np.inf)
        lg = np.maximum(lg, -700.0)   # exp(-700) = 0 in float64: a body without a heater
        return cls(jnp.log(jnp.asarray(capacity, float)), jnp.log(jnp.asarray(loss, float)),
                   jnp.log(jnp.asarray(np.asarray(coupling, float).reshape(-1))), jnp.asarray(lg),
                   edges=edges, sensors=sensors, ts=ts)

    @property
    def ts(self) -> float:
        return self.ts_

    def continuous(self):
        c = jnp.exp(self.log_capacity)
        m = c.shape[0]
        L = jnp.diag(jnp.exp(self.log_loss))
        if self.edges:
            g = jnp.exp(self.log_coupling)
            i = jnp.array([e[0] for e in self.edges])
            j = jnp.array([e[1] for e in self.edges])
            Lc = jnp.zeros((m, m), c.dtype).at[i, j].add(-g).at[j, i].add(-g)
            Lc = Lc - jnp.diag(jnp.sum(Lc, axis=1))
            L = L + Lc
        A = -L / c[:, None]
        B = jnp.exp(self.log_gain) / c[:, None]
        Bw = (jnp.exp(self.log_loss) / c)[:, None]
        return A, B, Bw

    def to_statespace(self) -> StateSpace:
        A, B, Bw = self.continuous()
        m, nu = B.shape
        Ad, BB = zoh(A, jnp.concatenate([B, Bw], axis=1), self.ts_)
        C = jnp.eye(m, dtype=Ad.dtype)[jnp.array(self.sensors)]
        return StateSpace(Ad, BB[:, :nu], C, ts=self.ts_, Bw=BB[:, nu:])


# ------------------------------------------------------------------------ start values


def first_order_start(y, u, w=None, ts: float = 1.0, capacity: float = NOMINAL_CAPACITY):
    """Start values from a least-squares first-order ARX fit per zone.

    $y_i(k+1) = a_i y_i(k) + \\sum_j b_{ij} u_j(k) + c_i$ (or $(1-a_i) T_s(k)$ when the
    surroundings are measured), mapped to $G_i/C_i = -\\log a_i / T_s$ and
    $n_{ij} = b_{ij} G_i / (1 - a_i)$. Returns `(loss (N,), gain (N, nu), surroundings)` in W/K,
    W, °C, clipped to positive values.
    """
    y = np.asarray(y, float)
    u = np.asarray(u, float)
    T, n = y.shape
    nu = u.shape[1]
    loss = np.empty(n)
    gain = np.empty((n, nu))
    ts_est = []
    for i in range(n):
        if w is not None:
            ws = np.asarray(w, float)[:-1, 0]
            X = np.column_stack([y[:-1, i] - ws, u[:-1]])
            target = y[1:, i] - ws
        else:
            X = np.column_stack([y[:-1, i], u[:-1], np.ones(T - 1)])
            target = y[1:, i]
        coef = np.linalg.lstsq(X, target, rcond=None)[0]
        a = float(np.clip(coef[0], 0.5, 0.9995))
        rate = -np.log(a) / ts
        loss[i] = rate * capacity
        b = np.asarray(coef[1:1 + nu])
        bpos = np.clip(b, 1e-3 * max(np.max(np.abs(b)), 1e-9), None)
        gain[i] = bpos * rate * capacity / (1 - a)
        if w is None:
            ts_est.append(coef[-1] / (1 - a))
    surr = float(np.median(ts_est)) if ts_est else float(np.mean(np.asarray(w)[:, 0]))
    if w is None:
        surr = float(np.clip(surr, np.min(y) - 200.0, np.min(y)))
    # off-diagonal gains: never start at ~0 (log parameters move slowly from there)
    diag = np.diag(gain) if nu == n else np.full(n, gain.max())
    gain = np.maximum(gain, 0.02 * np.max(diag))
    return loss, gain, surr


def greybox_initial_state(model: BedModel, y0) -> Array:
    """State of `model` whose output equals the measured temperatures `y0`."""
    return model.to_statespace().initial_state(jnp.asarray(y0))


__all__ = [
    "NOMINAL_CAPACITY",
    "BedModel",
    "ExtendedBedModel",
    "first_order_start",
    "greybox_initial_state",
    "zoh",
]
