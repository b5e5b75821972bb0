"""The virtual printer: a nonlinear, higher-fidelity model of a Powder Bed Fusion bed.

It is the plant jthermo makes data with and tests controllers against, richer than any model
it fits. With no effect switched on it *is* the linear grey-box bed model of the thesis
(Eriksson & Hanses 2019, eq. 3.5):

$$C_i \\dot T_i = -G_i (T_i - T_s) + \\sum_j n_{ij} u_j ,$$

zones on a near-square grid, each heater reaching every zone through a Gaussian footprint
$n_{ij}$. Each physical effect is switched on by name with its own parameters
(`make_printer(effects={"radiative_loss": {"emissivity": 0.8}, "heater_lag": True})`):

| effect | what it adds | parameters (defaults in `EFFECTS`) |
| --- | --- | --- |
| `lateral_conduction` | heat flow between grid neighbours $k (T_j - T_i)$ | `conductance_W_K` |
| `radiative_loss` | $\\varepsilon\\sigma A (T^4 - T_s^4)$ in kelvin | `emissivity`, `area_m2` |
| `heat_accumulation` | a slow shared chamber/wall state the zones lose heat to | `share`, `time_constant_s`, `loss_ratio` |
| `heater_lag` | first-order lamp lag | `time_constant_s` |
| `input_delay` | dead time in whole samples | `delay_s` |
| `input_nonlinearity` | lamp power $u^p$ | `exponent` |
| `recoat_cooling` | a cold layer spread every `period_s`, sweeping the columns in `duration_s`, pulling zones towards `temperature_C` (a drop of `drop_C` at the window centre) | `period_s`, `drop_C`, `duration_s`, `temperature_C`, `phase_s` |
| `laser_exposure` | absorbed laser power on a per-layer pattern of zones | `power_W`, `exposure_s`, `fraction`, `start_s`, `period_s` |
| `ambient_variation` | drift of the surroundings (sinusoid + random walk) | `amplitude_C`, `period_s`, `walk_C`, `measured` |
| `sensor_noise` | white + AR(1) coloured measurement noise | `white_std_C`, `coloured_std_C`, `pole` |
| `sensor_offset` | a constant bias per zone sensor | `std_C` (or `offsets_C`) |

Conventions that keep the operating point where the data are taken: with `radiative_loss`,
`loss` stays the total loss conductance at the window centre (the linear part gives up the
radiation's secant share); with `heat_accumulation`, `loss` stays the steady-state loss of a
uniform bed; with `input_nonlinearity`, power = $0.5^{1-p} u^p$ (equal to u at the nominal input
0.5). Default parameters (PA12, seed 0): C ≈ 36 J/K, G ≈ 0.6 W/K (τ = C/G ≈ 60 s), heater
footprint width 0.7 zone, surroundings 145 °C, so that u ≈ 0.5 holds the 172–176 °C window.

`areas=True` adds the thesis' areas 1–3 (wall heaters, build plate, powder container) as extra
states, each with its own heater input and thermocouple output (inputs/outputs N+1..N+3).

Integration: the linear part (zones, chamber, lamps, areas) is discretised exactly (zero-order
hold, a matrix exponential); radiation and the recoat sweep enter through fixed sub-steps of an
exponential Runge–Kutta scheme (ETD2RK, Cox & Matthews 2002). Without those effects one step is
the exact ZOH step, so the effect-free printer equals `BedModel.from_physical` to round-off.

Disturbances enter `step` through `PrinterDisturbance` (per sample: a recoat-start flag, laser
power per zone in W, surroundings temperature in °C); `disturbances(...)` builds them for a run.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .data import IOData, from_arrays
from .errors import ConfigError, ModelError

KELVIN = 273.15
SIGMA = 5.670374419e-8          # Stefan–Boltzmann, W/(m² K⁴)
ZONE_AREA = 0.01                # m², one 10 cm × 10 cm zone
HEATED_DEPTH = 0.004            # m, effective depth of powder that follows the surface temperature
NOMINAL_INPUT = 0.5             # power fraction that holds the bed at the window centre
AREA_NAMES = ("wall", "plate", "container")


# ----------------------------------------------------------------------------- powders


@dataclasses.dataclass(frozen=True)
class Powder:
    """Material preset: bulk properties and the print window (°C)."""

    name: str
    density: float              # kg/m³, bulk powder
    heat_capacity: float        # J/(kg K)
    emissivity: float           # -
    conductivity: float         # W/(m K), bulk powder
    window: tuple[float, float]  # °C, target bed window
    fresh_temperature: float    # °C, new powder leaving the container

    @property
    def target(self) -> float:
        return 0.5 * (self.window[0] + self.window[1])


POWDERS: dict[str, Powder] = {
    "PA12": Powder("PA12", 450.0, 2000.0, 0.90, 0.10, (172.0, 176.0), 100.0),
    "PA11": Powder("PA11", 500.0, 2100.0, 0.92, 0.12, (186.0, 190.0), 110.0),
}


# ----------------------------------------------------------------------------- effects

#: default parameters of every effect (units in the names)
EFFECTS: dict[str, dict[str, Any]] = {
    "lateral_conduction": {"conductance_W_K": None},          # None: from powder conductivity
    "radiative_loss": {"emissivity": None, "area_m2": ZONE_AREA},
    "heat_accumulation": {"share": 0.5, "time_constant_s": 1500.0, "loss_ratio": 1.0},
    "heater_lag": {"time_constant_s": 10.0},
    "input_delay": {"delay_s": 3},
    "input_nonlinearity": {"exponent": 1.5},
    "recoat_cooling": {"period_s": 60.0, "drop_C": 3.0, "duration_s": 8.0, "temperature_C": None,
                       "phase_s": 20.0},
    "laser_exposure": {"power_W": 8.0, "exposure_s": 15.0, "fraction": 0.5, "start_s": 10.0,
                       "period_s": 60.0},
    "ambient_variation": {"amplitude_C": 1.5, "period_s": 1800.0, "walk_C": 0.03,
                          "measured": False},
    "sensor_noise": {"white_std_C": 0.05, "coloured_std_C": 0.1, "pole": 0.9},
    "sensor_offset": {"std_C": 0.5, "offsets_C": None},
}

#: parameters that fix shapes or schedules: kept as Python values (static), not array leaves
_STATIC_PARAMS = {("input_delay", "delay_s"), ("ambient_variation", "measured"),
                  ("recoat_cooling", "period_s"), ("recoat_cooling", "duration_s"),
                  ("recoat_cooling", "phase_s"), ("laser_exposure", "exposure_s"),
                  ("laser_exposure", "fraction"), ("laser_exposure", "start_s"),
                  ("laser_exposure", "period_s"), ("ambient_variation", "period_s")}


def grid_shape(zones: int) -> tuple[int, int]:
    """(rows, cols) of the near-square grid: rows = floor(sqrt N), cols = ceil(N / rows)."""
    rows = max(1, int(math.floor(math.sqrt(zones))))
    return rows, int(math.ceil(zones / rows))


def grid_positions(zones: int) -> np.ndarray:
    """`(N, 2)` (row, column) positions with unit spacing, row-major."""
    _, cols = grid_shape(zones)
    idx = np.arange(zones)
    return np.stack([idx // cols, idx % cols], axis=1).astype(float)


def grid_edges(zones: int) -> tuple[tuple[int, int], ...]:
    """Pairs (i, j), i < j, of zones that share a grid side."""
    pos = grid_positions(zones)
    out = []
    for i in range(zones):
        for j in range(i + 1, zones):
            if abs(pos[i] - pos[j]).sum() == 1.0:
                out.append((i, j))
    return tuple(out)


# ----------------------------------------------------------------------------- state & disturbance


class PrinterState(eqx.Module):
    """State of the virtual printer.

    - `z`: the linear states: zone temperatures (°C), then the chamber (°C, heat accumulation),
      lamp powers (power fraction, heater lag), area temperatures (°C, areas 1–3), as present.
    - `buffer`: the last `delay` inputs, oldest first (input delay), `(delay, nu)`.
    - `since`: seconds since the last recoat started.
    """

    z: Float[Array, " nz"]
    buffer: Float[Array, "delay nu"]
    since: Float[Array, ""]


class PrinterDisturbance(eqx.Module):
    """Exogenous signals at one sample (or `(T, ...)` for a run).

    - `recoat`: 1.0 at the sample a recoat starts, else 0.
    - `laser`: absorbed laser power per zone, W.
    - `ambient`: surroundings temperature, °C.
    """

    recoat: Float[Array, ""]
    laser: Float[Array, " zones"]
    ambient: Float[Array, ""]


class _Discrete(eqx.Module):
    E: Array        # e^{A h}
    P1: Array       # h φ1(A h)
    P2: Array       # h φ2(A h)


def _expm(M: Array, squarings: int = 8, order: int = 14) -> Array:
    """Matrix exponential by scaling and squaring with a Taylor polynomial (fixed, branch-free:
    cheap to compile and to differentiate). Accurate to round-off for ||M|| up to ~100, far
    beyond the printer's sample-time matrices (||A Ts|| ~ 0.1–2)."""
    X = M / (2.0 ** squarings)
    eye = jnp.eye(M.shape[0], dtype=M.dtype)
    # F = e^X - I = X (I + X/2! + X^2/3! + ...), squared as (I + F)^2 = I + (2F + F^2) so that
    # the small part keeps its relative precision
    P = eye + X / (order + 1)
    for k in range(order, 1, -1):
        P = eye + (X @ P) / k
    F = X @ P
    for _ in range(squarings):
        F = 2.0 * F + F @ F
    return eye + F


def _phi_matrices(A: Array, h: float) -> _Discrete:
    n = A.shape[0]
    eye = jnp.eye(n, dtype=A.dtype)
    zero = jnp.zeros((n, n), A.dtype)
    M = jnp.block([[A * h, eye * h, zero], [zero, zero, eye * h], [zero, zero, zero]])
    F = _expm(M)
    return _Discrete(E=F[:n, :n], P1=F[:n, n:2 * n], P2=F[:n, 2 * n:] / h)


def _safe_power(u, p):
    pos = u > 0
    return jnp.where(pos, jnp.where(pos, u, 1.0) ** p, 0.0)


# ----------------------------------------------------------------------------- the printer


class Printer(eqx.Module):
    """The virtual printer (see the module docstring). Build it with `make_printer`.

    Array fields are differentiable parameters: `capacity` $C_i$ (J/K), `loss` $G_i = 1/R_{s,i}$
    (W/K), `gain` $n_{ij}$ (W per unit input of heater j into zone i), `surroundings` $T_s$ (°C),
    and the effect parameters in `effects[name][param]`.
    """

    capacity: Float[Array, " zones"]          # J/K
    loss: Float[Array, " zones"]              # W/K, to the surroundings
    gain: Float[Array, "zones zones"]         # W per unit input
    surroundings: Float[Array, ""]            # °C
    effects: dict                             # name -> {param: array}
    area: dict                                # areas 1–3 parameters (empty without areas)
    static: tuple = eqx.field(static=True)    # ((name, param, value), ...) schedule parameters
    zones: int = eqx.field(static=True)
    delay: int = eqx.field(static=True)       # input dead time in samples
    substeps: int = eqx.field(static=True)    # sub-steps per sample for the nonlinear effects
    ts: float = eqx.field(static=True)        # s
    powder: str = eqx.field(static=True)
    window: tuple = eqx.field(static=True)    # °C print window
    has_areas: bool = eqx.field(static=True)

    def __check_init__(self):
        n = self.zones
        if self.capacity.shape != (n,) or self.loss.shape != (n,) or self.gain.shape != (n, n):
            raise ModelError(f"Printer: capacity/loss must be ({n},) and gain ({n}, {n}); got "
                             f"{self.capacity.shape}, {self.loss.shape}, {self.gain.shape}")

    # -- sizes ---------------------------------------------------------------------------
    @property
    def enabled(self) -> tuple[str, ...]:
        return tuple(self.effects)

    def has(self, name: str) -> bool:
        return name in self.effects

    def param(self, name: str, key: str):
        """A schedule (static) parameter of an effect, falling back to the defaults."""
        for n, k, v in self.static:
            if n == name and k == key:
                return v
        if name in self.effects and key in self.effects[name]:
            return self.effects[name][key]
        return EFFECTS[name][key]

    @property
    def n_inputs(self) -> int:
        return self.zones + (3 if self.has_areas else 0)

    @property
    def n_outputs(self) -> int:
        return self.n_inputs

    @property
    def n_signals(self) -> int:
        return 1

    @property
    def grid(self) -> tuple[int, int]:
        return grid_shape(self.zones)

    @property
    def edges(self) -> tuple[tuple[int, int], ...]:
        return grid_edges(self.zones)

    def _layout(self) -> dict[str, slice]:
        n, i = self.zones, self.zones
        out = {"T": slice(0, n)}
        if self.has("heat_accumulation"):
            out["chamber"] = slice(i, i + 1)
            i += 1
        if self.has("heater_lag"):
            out["lamp"] = slice(i, i + n)
            i += n
        if self.has_areas:
            out["areas"] = slice(i, i + 3)
            i += 3
        out["n"] = slice(0, i)
        return out

    @property
    def n_states(self) -> int:
        return self._layout()["n"].stop

    @property
    def nonlinear(self) -> bool:
        return self.has("radiative_loss") or self.has("recoat_cooling")

    # -- the continuous-time model -------------------------------------------------------
    def linear_system(self):
        """Continuous linear part $\\dot z = A z + B_p p + b_s T_s + B_l q_{laser}$.

        **Returns:** `(A, Bp, bs, Bl)` with `p` the heater power fractions after delay and
        nonlinearity (`nu`), `T_s` the surroundings (°C) and `q_laser` the laser power (W).
        """
        L = self._layout()
        n, nz, nu = self.zones, L["n"].stop, self.n_inputs
        C, G, ngain = self.capacity, self.loss, self.gain
        dt = C.dtype
        A = jnp.zeros((nz, nz), dt)
        Bp = jnp.zeros((nz, nu), dt)
        bs = jnp.zeros((nz,), dt)
        T = jnp.arange(n)
        if self.has("radiative_loss"):
            # `loss` is the total loss at the window centre: radiation takes its secant share
            G = jnp.maximum(G - self._radiation_secant(), 0.05 * G)
        g_env = G
        if self.has("heat_accumulation"):
            p = self.effects["heat_accumulation"]
            share = p["share"]
            # `loss` stays the steady-state loss: the chamber sits a fraction rho of the way
            # from the surroundings to the bed, so the zones lose G (1 - share rho) at rest
            rho = 1.0 / (1.0 + p["loss_ratio"])
            G = G / (1.0 - share * rho)
            g_ch = share * G
            g_env = (1.0 - share) * G
            g_out = p["loss_ratio"] * jnp.sum(g_ch)
            cap_ch = p["time_constant_s"] * (g_out + jnp.sum(g_ch))
            c = L["chamber"].start
            A = A.at[T, c].set(g_ch / C)
            A = A.at[c, T].set(g_ch / cap_ch)
            A = A.at[c, c].set(-(jnp.sum(g_ch) + g_out) / cap_ch)
            bs = bs.at[c].set(g_out / cap_ch)
            A = A.at[T, T].add(-g_ch / C)
        A = A.at[T, T].add(-g_env / C)
        bs = bs.at[T].set(g_env / C)
        if self.has("lateral_conduction"):
            k = self.effects["lateral_conduction"]["conductance_W_K"]
            lap = np.zeros((n, n))
            for i, j in self.edges:
                lap[i, j] = lap[j, i] = 1.0
                lap[i, i] -= 1.0
                lap[j, j] -= 1.0
            A = A.at[:n, :n].add(k * jnp.asarray(lap, dt) / C[:, None])
        if self.has("heater_lag"):
            tau = self.effects["heater_lag"]["time_constant_s"]
            lp = L["lamp"].start
            A = A.at[:n, lp:lp + n].set(ngain / C[:, None])
            A = A.at[lp + T, lp + T].set(-1.0 / tau)
            Bp = Bp.at[lp + T, T].set(1.0 / tau)
        else:
            Bp = Bp.at[:n, :n].set(ngain / C[:, None])
        if self.has_areas:
            a = self.area
            s = L["areas"].start
            gw, gp = a["wall_coupling"], a["plate_coupling"]     # (N,) W/K each
            A = A.at[T, T].add(-(gw + gp) / C)
            A = A.at[T, s].set(gw / C)
            A = A.at[T, s + 1].set(gp / C)
            ca, la, pa, gwc = a["capacity"], a["loss"], a["power"], a["wall_container"]
            A = A.at[s, T].set(gw / ca[0])
            A = A.at[s + 1, T].set(gp / ca[1])
            A = A.at[s, s].set(-(la[0] + jnp.sum(gw) + gwc) / ca[0])
            A = A.at[s + 1, s + 1].set(-(la[1] + jnp.sum(gp)) / ca[1])
            A = A.at[s + 2, s + 2].set(-(la[2] + gwc) / ca[2])
            A = A.at[s, s + 2].set(gwc / ca[0])
            A = A.at[s + 2, s].set(gwc / ca[2])
            bs = bs.at[s:s + 3].set(la / ca)
            Bp = Bp.at[s + jnp.arange(3), n + jnp.arange(3)].set(pa / ca)
        Bl = jnp.zeros((nz, n), dt).at[T, T].set(1.0 / C)
        return A, Bp, bs, Bl

    def _radiation_secant(self):
        """Radiated power per kelvin above the surroundings at the window centre (W/K)."""
        p = self.effects["radiative_loss"]
        Tc, Ts = self.window_centre, self.surroundings
        q = p["emissivity"] * SIGMA * p["area_m2"] * ((Tc + KELVIN) ** 4 - (Ts + KELVIN) ** 4)
        return q / (Tc - Ts)

    def _nonlinear(self, z, t, ambient):
        """Radiation and recoat terms on the zone rows at time `t` s since the recoat start."""
        n = self.zones
        T = z[:n]
        f = jnp.zeros_like(z)
        if self.has("radiative_loss"):
            p = self.effects["radiative_loss"]
            q = p["emissivity"] * SIGMA * p["area_m2"] * ((T + KELVIN) ** 4 - (ambient + KELVIN) ** 4)
            f = f.at[:n].add(-q / self.capacity)
        if self.has("recoat_cooling"):
            p = self.effects["recoat_cooling"]
            rows, cols = self.grid
            col = jnp.asarray(grid_positions(n)[:, 1], z.dtype)
            passing = self.param("recoat_cooling", "duration_s") / cols
            fresh = p["temperature_C"]
            if self.has_areas:          # new powder comes from the container (area 3)
                fresh = z[self._layout()["areas"].start + 2]
            frac = jnp.clip(p["drop_C"] / (self.window_centre - p["temperature_C"]), 0.0, 0.9)
            rate = -jnp.log1p(-frac) / passing
            inside = (t >= col * passing) & (t < (col + 1) * passing)
            f = f.at[:n].add(-jnp.where(inside, rate, 0.0) * (T - fresh))
        return f

    @property
    def window_centre(self) -> float:
        return 0.5 * (self.window[0] + self.window[1])

    def _power(self, u):
        """Heater power fractions after the lamp nonlinearity (bed heaters only)."""
        if self.has("input_nonlinearity"):
            e = self.effects["input_nonlinearity"]["exponent"]
            n = self.zones
            # power ∝ u^e, normalised to equal u at the nominal input
            return u.at[:n].set(NOMINAL_INPUT ** (1.0 - e) * _safe_power(u[:n], e))
        return u

    def discretise(self) -> DiscretePrinter:
        """Precompute the sample-time matrices once (what `closedloop.simulate` calls)."""
        A, Bp, bs, Bl = self.linear_system()
        m = self.substeps if self.nonlinear else 1
        return DiscretePrinter(printer=self, disc=_phi_matrices(A, self.ts / m), Bp=Bp, bs=bs,
                               Bl=Bl, m=m)

    # -- plant interface -----------------------------------------------------------------
    def default_disturbance(self) -> PrinterDisturbance:
        dt = self.capacity.dtype
        return PrinterDisturbance(recoat=jnp.zeros((), dt), laser=jnp.zeros(self.zones, dt),
                                  ambient=jnp.asarray(self.surroundings, dt))

    def step(self, x: PrinterState, u: Float[Array, " nu"],
             d: PrinterDisturbance | None = None) -> PrinterState:
        """One sample Ts ahead (computes the discretisation: use `discretise()` in loops)."""
        return self.discretise().step(x, u, d)

    def output(self, x: PrinterState) -> Float[Array, " ny"]:
        """Sensor readings without noise, °C: zone temperatures plus offsets, then areas 1–3."""
        y = self.temperatures(x)
        if self.has("sensor_offset"):
            y = y.at[:self.zones].add(self.effects["sensor_offset"]["offsets_C"])
        return y

    def temperatures(self, x: PrinterState) -> Float[Array, " ny"]:
        """True temperatures at the sensor positions (zones, then areas), °C."""
        L = self._layout()
        T = x.z[L["T"]]
        if self.has_areas:
            T = jnp.concatenate([T, x.z[L["areas"]]])
        return T

    def initial_state(self, y0: Float[Array, " ny"] | None = None, *,
                      ambient: float | Array | None = None) -> PrinterState:
        """The steady state at which the (true) zone temperatures equal `y0` (°C).

        `y0` of length N (zones; areas at their defaults) or N+3 (with areas). None: every
        zone at the window centre. The heaters (and lamps, delay buffer) hold the power
        that keeps that state, which may lie outside [0, 1] if `y0` is out of reach.
        """
        n = self.zones
        dt = self.capacity.dtype
        Ts = self.surroundings if ambient is None else jnp.asarray(ambient, dt)
        if y0 is None:
            y0 = jnp.full((n,), self.window_centre, dt)
        y0 = jnp.asarray(y0, dt)
        if y0.ndim == 0:
            y0 = jnp.full((n,), y0)
        if y0.shape[0] not in (n, self.n_outputs):
            raise ModelError(f"Printer.initial_state: y0 has {y0.shape[0]} values, expected {n}"
                             f" or {self.n_outputs}")
        return _initial_state(self, y0, Ts)

    def _initial_state(self, y0, Ts) -> PrinterState:
        n = self.zones
        dt = self.capacity.dtype
        L = self._layout()
        A, Bp, bs, _ = self.linear_system()
        nz = L["n"].stop
        known = np.zeros(nz, bool)
        known[:n] = True
        zk = jnp.zeros(nz, dt).at[:n].set(y0[:n])
        if self.has_areas:
            s = L["areas"].start
            known[s:s + 3] = True
            ya = y0[n:] if y0.shape[0] > n else self.area["setpoint"]
            zk = zk.at[s:s + 3].set(ya)
        unknown = np.flatnonzero(~known)
        f = self._nonlinear(zk, jnp.asarray(1e9, dt), Ts)
        rhs = -(A[:, known] @ zk[known] + bs * Ts + f)
        M = jnp.concatenate([A[:, unknown], Bp], axis=1)
        sol = jnp.linalg.solve(M, rhs)
        z = zk.at[unknown].set(sol[:unknown.size])
        p = sol[unknown.size:]
        u = p
        if self.has("input_nonlinearity"):
            e = self.effects["input_nonlinearity"]["exponent"]
            u = u.at[:n].set(_safe_power(p[:n] / NOMINAL_INPUT ** (1.0 - e), 1.0 / e))
        buf = jnp.broadcast_to(u, (self.delay, self.n_inputs)).astype(dt)
        return PrinterState(z=z, buffer=buf, since=jnp.asarray(1e9, dt))

    def steady_input(self, y0=None, *, ambient=None) -> Float[Array, " nu"]:
        """The constant input that holds the bed at `y0` (see `initial_state`)."""
        return _steady_u(self, self.initial_state(y0, ambient=ambient), ambient)

    def ambient_state(self, ambient=None) -> PrinterState:
        """Everything at the surroundings temperature, heaters off (a cold start)."""
        dt = self.capacity.dtype
        Ts = self.surroundings if ambient is None else jnp.asarray(ambient, dt)
        L = self._layout()
        z = jnp.full((L["n"].stop,), Ts, dt)
        if "lamp" in L:
            z = z.at[L["lamp"]].set(0.0)
        return PrinterState(z=z, buffer=jnp.zeros((self.delay, self.n_inputs), dt),
                            since=jnp.asarray(1e9, dt))

    def linear_bed_parameters(self) -> dict[str, Array]:
        """The thesis' grey-box bed parameters: `capacity` (J/K), `loss` (W/K), `gain` (W)."""
        return {"capacity": self.capacity, "loss": self.loss, "gain": self.gain}

    def sample_noise(self, key, n_samples: int, white_std: float = 0.0) -> Float[Array, "T ny"]:
        """Measurement noise `(T, ny)`: white `white_std` plus the `sensor_noise` effect
        (white + stationary AR(1)) on the zone sensors; thermocouples get the white part."""
        dt = self.capacity.dtype
        k1, k2, k3 = jax.random.split(key, 3)
        ny = self.n_outputs
        v = white_std * jax.random.normal(k1, (n_samples, ny), dt)
        if self.has("sensor_noise"):
            p = self.effects["sensor_noise"]
            v = v + p["white_std_C"] * jax.random.normal(k2, (n_samples, ny), dt)
            a = p["pole"]
            e = jax.random.normal(k3, (n_samples, self.zones), dt)
            g = p["coloured_std_C"] * jnp.sqrt(1.0 - a ** 2)

            def body(c, ek):
                c = a * c + g * ek
                return c, c

            c0 = p["coloured_std_C"] * e[0]
            _, col = jax.lax.scan(body, c0, e[1:])
            col = jnp.concatenate([c0[None], col], axis=0)
            v = v.at[:, :self.zones].add(col)
        return v


@eqx.filter_jit
def _initial_state(printer: Printer, y0, Ts) -> PrinterState:
    return printer._initial_state(y0, Ts)


def _steady_u(printer: Printer, x: PrinterState, ambient) -> Array:
    n = printer.zones
    dt = printer.capacity.dtype
    Ts = printer.surroundings if ambient is None else jnp.asarray(ambient, dt)
    A, Bp, bs, _ = printer.linear_system()
    f = printer._nonlinear(x.z, jnp.asarray(1e9, dt), Ts)
    r = -(A @ x.z + bs * Ts + f)
    p = jnp.linalg.lstsq(Bp, r)[0]
    if printer.has("input_nonlinearity"):
        e = printer.effects["input_nonlinearity"]["exponent"]
        p = p.at[:n].set(_safe_power(p[:n] / NOMINAL_INPUT ** (1.0 - e), 1.0 / e))
    return p


class DiscretePrinter(eqx.Module):
    """A printer with its sample-time matrices precomputed: same `step`/`output` interface."""

    printer: Printer
    disc: _Discrete
    Bp: Array
    bs: Array
    Bl: Array
    m: int = eqx.field(static=True)

    def step(self, x: PrinterState, u, d: PrinterDisturbance | None = None) -> PrinterState:
        pr = self.printer
        if d is None:
            d = pr.default_disturbance()
        u = jnp.asarray(u, self.Bp.dtype)
        if pr.delay:
            u_now = x.buffer[0]
            buffer = jnp.concatenate([x.buffer[1:], u[None]], axis=0)
        else:
            u_now, buffer = u, x.buffer
        p = pr._power(u_now)
        b = self.Bp @ p + self.bs * d.ambient + self.Bl @ d.laser
        since = jnp.where(d.recoat > 0.5, 0.0, x.since)
        E, P1, P2 = self.disc.E, self.disc.P1, self.disc.P2
        if self.m == 1 and not pr.nonlinear:
            z = E @ x.z + P1 @ b
        else:
            h = pr.ts / self.m

            def sub(z, j):
                t = since + j * h
                n0 = b + pr._nonlinear(z, t, d.ambient)
                a = E @ z + P1 @ n0
                n1 = b + pr._nonlinear(a, t + h, d.ambient)
                return a + P2 @ (n1 - n0), None

            z, _ = jax.lax.scan(sub, x.z, jnp.arange(self.m, dtype=x.z.dtype))
        return PrinterState(z=z, buffer=buffer, since=since + pr.ts)

    def output(self, x):
        return self.printer.output(x)

    def temperatures(self, x):
        return self.printer.temperatures(x)


# ----------------------------------------------------------------------------- construction


def _normalise_effects(effects) -> dict[str, dict[str, Any]]:
    if effects is None:
        return {}
    if isinstance(effects, str):
        effects = [effects]
    if isinstance(effects, Mapping):
        items = list(effects.items())
    else:
        items = [(e, True) for e in effects]
    out = {}
    for name, params in items:
        if name not in EFFECTS:
            raise ConfigError(f"make_printer: unknown effect `{name}` (known: {', '.join(EFFECTS)})")
        if params is False or params is None:
            continue
        if params is True:
            params = {}
        if not isinstance(params, Mapping):
            raise ConfigError(f"make_printer: parameters of `{name}` must be a dict or True")
        for k in params:
            if k not in EFFECTS[name]:
                raise ConfigError(f"make_printer: effect `{name}` has no parameter `{k}` "
                                  f"(known: {', '.join(EFFECTS[name])})")
        out[name] = {**EFFECTS[name], **dict(params)}
    return out


def make_printer(zones: int = 4, effects: Mapping[str, Mapping] | Iterable[str] = (), *,
                 powder: str = "PA12", seed: int = 0, areas: bool = False,
                 **overrides) -> Printer:
    """Build a virtual printer.

    **Arguments:**
    - `zones`: number of bed zones N (1–256), on a near-square grid.
    - `effects`: effect names (defaults) or `{name: {param: value}}` (see `EFFECTS`).
    - `powder`: a key of `POWDERS` (`"PA12"`, `"PA11"`): capacity, emissivity, conductivity,
      print window, and the chamber (surroundings) temperature that goes with it.
    - `seed`: zone-to-zone variation of capacity, loss and heater power (±8 %), sensor offsets.
    - `areas`: add areas 1–3 (wall, build plate, container) with heaters and thermocouples.
    - `overrides`: `capacity`, `loss` (W/K), `gain` (N×N, W), `surroundings` (°C),
      `footprint_width` (grid units), `heater_power` (W, total per zone at u = 1),
      `spread` (relative variation), `substeps`, `ts`, `dtype`.
    """
    if not isinstance(zones, (int, np.integer)) or not 1 <= zones <= 256:
        raise ConfigError(f"make_printer: zones must be an integer in 1..256, got {zones!r}")
    if powder not in POWDERS:
        raise ConfigError(f"make_printer: unknown powder `{powder}` (known: {', '.join(POWDERS)})")
    known = {"capacity", "loss", "gain", "surroundings", "footprint_width", "heater_power",
             "spread", "substeps", "ts", "dtype"}
    bad = [k for k in overrides if k not in known]
    if bad:
        raise ConfigError(f"make_printer: unknown option `{bad[0]}` (known: {', '.join(sorted(known))})")
    pw = POWDERS[powder]
    n = int(zones)
    eff = _normalise_effects(effects)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), n, 7]))
    spread = float(overrides.get("spread", 0.08))
    jitter = lambda: 1.0 + spread * rng.uniform(-1.0, 1.0, n)
    cap_nominal = pw.density * pw.heat_capacity * ZONE_AREA * HEATED_DEPTH     # J/K (≈36 for PA12)
    loss_nominal = 0.6                                                         # W/K (τ ≈ 60 s)
    rise = 29.0                      # K above the surroundings at the nominal input 0.5
    capacity = np.asarray(overrides.get("capacity", cap_nominal * jitter()), float)
    loss = np.asarray(overrides.get("loss", loss_nominal * jitter()), float)
    power_scale = jitter()
    if "gain" in overrides:
        gain = np.asarray(overrides["gain"], float)
    else:
        width = float(overrides.get("footprint_width", 0.7))
        pos = grid_positions(n)
        d2 = ((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1)
        foot = np.exp(-d2 / (2 * width ** 2)) * power_scale[None, :]
        total = float(overrides.get("heater_power", loss_nominal * rise / NOMINAL_INPUT))
        gain = foot * total / foot.sum(1).mean()
    surroundings = float(overrides.get("surroundings", pw.target - rise))
    for name, arr, shape in (("capacity", capacity, (n,)), ("loss", loss, (n,)), ("gain", gain, (n, n))):
        if arr.shape != shape:
            raise ConfigError(f"make_printer: `{name}` has shape {arr.shape}, expected {shape}")
        if not np.all(np.isfinite(arr)):
            raise ConfigError(f"make_printer: `{name}` must be finite")
    if np.any(capacity <= 0) or np.any(loss <= 0) or np.any(gain < 0):
        raise ConfigError("make_printer: capacity and loss must be > 0 and gain >= 0")
    dtype = overrides.get("dtype", None) or jnp.result_type(float)

    # effect parameters: fill powder-dependent defaults, split static from array leaves
    static = []
    leaves: dict[str, dict[str, Array]] = {}
    for name, params in eff.items():
        params = dict(params)
        if name == "lateral_conduction" and params["conductance_W_K"] is None:
            params["conductance_W_K"] = 1.5 * pw.conductivity          # 0.15 W/K for PA12
        if name == "radiative_loss" and params["emissivity"] is None:
            params["emissivity"] = pw.emissivity
        if name == "recoat_cooling" and params["temperature_C"] is None:
            params["temperature_C"] = pw.fresh_temperature
        if name == "sensor_offset":
            off = params.pop("offsets_C")
            std = params.pop("std_C")
            if off is None:
                off = std * rng.standard_normal(n)
            off = np.asarray(off, float)
            if off.shape != (n,):
                raise ConfigError(f"make_printer: `offsets_C` must have {n} values")
            params = {"offsets_C": off}
        leaves[name] = {}
        for k, v in params.items():
            if (name, k) in _STATIC_PARAMS:
                static.append((name, k, v))
            else:
                leaves[name][k] = jnp.asarray(v, dtype)
    delay = 0
    if "input_delay" in eff:
        ds = eff["input_delay"]["delay_s"]
        ts = float(overrides.get("ts", 1.0))
        delay = int(round(float(ds) / ts))
        if delay < 0 or abs(delay * ts - float(ds)) > 1e-9:
            raise ConfigError(f"make_printer: input_delay delay_s must be a whole number of samples, got {ds}")
    _check_effect_values(leaves, static)
    area = {}
    if areas:
        edge = np.zeros(n)
        rows, cols = grid_shape(n)
        pos = grid_positions(n)
        edge[(pos[:, 0] == 0) | (pos[:, 0] == rows - 1) | (pos[:, 1] == 0) | (pos[:, 1] == cols - 1)] = 1.0
        area = {
            "capacity": jnp.asarray([2000.0, 3000.0, 1500.0], dtype),   # J/K
            "loss": jnp.asarray([2.0, 3.0, 1.5], dtype),                # W/K to surroundings
            "power": jnp.asarray([60.0, 150.0, 20.0], dtype),           # W at u = 1
            "wall_coupling": jnp.asarray(0.05 * edge, dtype),           # W/K zone <-> wall
            "plate_coupling": jnp.full((n,), 0.1, dtype),               # W/K zone <-> plate
            "wall_container": jnp.asarray(0.5, dtype),                  # W/K wall <-> container
            "setpoint": jnp.asarray([surroundings + 10.0, pw.target - 6.0, surroundings + 5.0], dtype),
        }
    substeps = int(overrides.get("substeps", 10))
    return Printer(capacity=jnp.asarray(capacity, dtype), loss=jnp.asarray(loss, dtype),
                   gain=jnp.asarray(gain, dtype), surroundings=jnp.asarray(surroundings, dtype),
                   effects=leaves, area=area, static=tuple(static), zones=n, delay=delay,
                   substeps=substeps, ts=float(overrides.get("ts", 1.0)), powder=powder,
                   window=tuple(pw.window), has_areas=bool(areas))


def _check_effect_values(leaves, static):
    def pos(name, key):
        if name in leaves and key in leaves[name] and not float(leaves[name][key]) > 0:
            raise ConfigError(f"make_printer: `{name}.{key}` must be > 0")
    pos("heater_lag", "time_constant_s")
    pos("heat_accumulation", "time_constant_s")
    pos("input_nonlinearity", "exponent")
    pos("radiative_loss", "area_m2")
    if "heat_accumulation" in leaves and not 0.0 < float(leaves["heat_accumulation"]["share"]) <= 1.0:
        raise ConfigError("make_printer: `heat_accumulation.share` must be in (0, 1]")
    if "sensor_noise" in leaves and not 0.0 <= float(leaves["sensor_noise"]["pole"]) < 1.0:
        raise ConfigError("make_printer: `sensor_noise.pole` must be in [0, 1)")
    for name, key, v in static:
        if key in ("period_s", "duration_s", "exposure_s") and not float(v) > 0:
            raise ConfigError(f"make_printer: `{name}.{key}` must be > 0")
        if key == "fraction" and not 0.0 <= float(v) <= 1.0:
            raise ConfigError(f"make_printer: `{name}.fraction` must be in [0, 1]")


# ----------------------------------------------------------------------------- steady state


@eqx.filter_jit
def steady_state(printer: Printer, u, *, ambient=None, iterations: int = 30) -> PrinterState:
    """The equilibrium for a constant input `u` (no recoat, no laser), by Newton's method
    on the continuous-time right-hand side (one linear solve when no effect is nonlinear)."""
    dt = printer.capacity.dtype
    Ts = printer.surroundings if ambient is None else jnp.asarray(ambient, dt)
    u = jnp.broadcast_to(jnp.asarray(u, dt), (printer.n_inputs,))
    A, Bp, bs, _ = printer.linear_system()
    b = Bp @ printer._power(u) + bs * Ts
    z = jnp.linalg.solve(A, -b)
    if printer.has("radiative_loss"):
        far = jnp.asarray(1e9, dt)

        def rhs(z):
            return A @ z + b + printer._nonlinear(z, far, Ts)

        def newton(z, _):
            return z - jnp.linalg.solve(jax.jacfwd(rhs)(z), rhs(z)), None

        z, _ = jax.lax.scan(newton, z, None, length=iterations)
    buf = jnp.broadcast_to(u, (printer.delay, printer.n_inputs)).astype(dt)
    return PrinterState(z=z, buffer=buf, since=jnp.asarray(1e9, dt))


# ----------------------------------------------------------------------------- disturbances


def _layer_starts(printer: Printer, n_samples: int, phase_s) -> Array:
    """Flags (T,) at the samples where a layer (recoat) starts."""
    if printer.has("recoat_cooling"):
        period = float(printer.param("recoat_cooling", "period_s"))
    else:
        period = float(printer.param("laser_exposure", "period_s"))
    pk = max(1, int(round(period / printer.ts)))
    k = jnp.arange(n_samples)
    ph = jnp.round(jnp.asarray(phase_s) / printer.ts).astype(k.dtype)
    return ((k >= ph) & (((k - ph) % pk) == 0)).astype(printer.capacity.dtype)


def disturbances(printer: Printer, n_samples: int, key, *, recoat: bool | None = None,
                 laser: bool | None = None, ambient: bool | None = None,
                 phase_s=None, drop_scale=1.0) -> PrinterDisturbance:
    """Disturbances `(T, ...)` for a run of `n_samples`, from the printer's effects.

    Recoat flags every `recoat_cooling.period_s` from `phase_s`; laser exposure on a random
    pattern (`fraction` of the zones) per layer, `start_s` after the layer starts, for
    `exposure_s`; surroundings following `ambient_variation` (a sinusoid of random phase plus a
    random walk) or constant. `recoat`/`laser`/`ambient` = False switch a part off; True
    requires the effect. `drop_scale` is unused by the printer physics and kept for builders.
    """
    dt = printer.capacity.dtype
    n, T = printer.zones, int(n_samples)
    k_pat, k_amb, k_walk = jax.random.split(key, 3)
    recoat = printer.has("recoat_cooling") if recoat is None else recoat
    laser = printer.has("laser_exposure") if laser is None else laser
    ambient = printer.has("ambient_variation") if ambient is None else ambient
    for flag, name in ((recoat, "recoat_cooling"), (laser, "laser_exposure"),
                       (ambient, "ambient_variation")):
        if flag and not printer.has(name):
            raise ConfigError(f"this scenario needs a printer with the `{name}` effect "
                              f"(make_printer(effects=[..., '{name}']))")
    if phase_s is None:
        phase_s = printer.param("recoat_cooling", "phase_s") if printer.has("recoat_cooling") else 0.0
    starts = _layer_starts(printer, T, phase_s)
    flags = starts if recoat else jnp.zeros(T, dt)
    q = jnp.zeros((T, n), dt)
    if laser:
        p = printer.effects["laser_exposure"]
        layer = jnp.cumsum(starts).astype(jnp.int32) - 1          # -1 before the first layer
        t_in = jnp.arange(T) - jnp.asarray(
            jax.lax.cummax(jnp.where(starts > 0, jnp.arange(T), -10 ** 9)), jnp.int32)
        t0 = int(round(float(printer.param("laser_exposure", "start_s")) / printer.ts))
        te = int(round(float(printer.param("laser_exposure", "exposure_s")) / printer.ts))
        on = (layer >= 0) & (t_in >= t0) & (t_in < t0 + te)
        frac = float(printer.param("laser_exposure", "fraction"))
        n_layers = int(T // max(1, int(round(float(
            printer.param("recoat_cooling" if printer.has("recoat_cooling") else "laser_exposure",
                          "period_s")) / printer.ts)))) + 2
        pattern = jax.random.bernoulli(k_pat, frac, (n_layers, n)).astype(dt)
        q = jnp.where(on[:, None], pattern[jnp.clip(layer, 0, n_layers - 1)], 0.0) * p["power_W"]
    amb = jnp.full((T,), printer.surroundings, dt)
    if ambient:
        p = printer.effects["ambient_variation"]
        period = float(printer.param("ambient_variation", "period_s"))
        phi = jax.random.uniform(k_amb, (), dt, 0.0, 2 * jnp.pi)
        t = printer.ts * jnp.arange(T, dtype=dt)
        walk = jnp.cumsum(jax.random.normal(k_walk, (T,), dt)) * p["walk_C"] * math.sqrt(printer.ts)
        amb = amb + p["amplitude_C"] * jnp.sin(2 * jnp.pi * t / period + phi) + walk
    return PrinterDisturbance(recoat=flags, laser=q, ambient=amb)


# ----------------------------------------------------------------------------- open loop


@eqx.filter_jit
def simulate_open_loop(printer: Printer, u: Float[Array, "T nu"],
                       d: PrinterDisturbance | None = None, x0: PrinterState | None = None):
    """Open-loop run: `(y, temperatures)`, each `(T, ny)`, noise-free; `y[k] = g(x_k)`."""
    u = jnp.asarray(u, printer.capacity.dtype)
    T = u.shape[0]
    if d is None:
        base = printer.default_disturbance()
        d = jax.tree.map(lambda a: jnp.broadcast_to(a, (T,) + a.shape), base)
    x0 = printer.initial_state() if x0 is None else x0
    plant = printer.discretise()

    def body(x, inp):
        uk, dk = inp
        return plant.step(x, uk, dk), (plant.output(x), plant.temperatures(x))

    _, (y, temps) = jax.lax.scan(body, x0, (u, d))
    return y, temps


def _prbs(seed: int, n_samples: int, n_channels: int, levels, hold=(3, 15)) -> np.ndarray:
    try:
        from .inputs import prbs as _ext
        out = np.asarray(_ext(seed, n_samples, n_channels, levels=tuple(levels), hold=tuple(hold)))
        if out.shape == (n_samples, n_channels):
            return out
    except (ImportError, AttributeError, TypeError):
        pass
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 11]))
    lo, hi = levels
    u = np.empty((n_samples, n_channels))
    for j in range(n_channels):
        level, t = int(rng.integers(0, 2)), 0
        while t < n_samples:
            h = int(rng.integers(hold[0], hold[1] + 1))
            u[t:t + h, j] = hi if level else lo
            t += h
            level = 1 - level
    return u


@eqx.filter_jit
def _generate_core(printer, u, key, u_mean, noise_std, steady: bool):
    T = u.shape[0]
    k_d, k_v = jax.random.split(key)
    d = disturbances(printer, T, k_d)
    x0 = steady_state(printer, u_mean) if steady else printer.ambient_state()
    y, _ = simulate_open_loop(printer, u, d, x0)
    return y + printer.sample_noise(k_v, T, noise_std), d


def input_names(printer: Printer) -> tuple[str, ...]:
    names = tuple(str(i + 1) for i in range(printer.zones))
    return names + (AREA_NAMES if printer.has_areas else ())


def generate(printer: Printer, experiment: str = "prbs", duration: float = 3600.0, *,
             seed: int = 0, levels=(0.3, 0.7), start: str = "steady",
             noise_std: float = 0.05) -> IOData:
    """Open-loop experiment on the printer, as validated `IOData` (absolute °C, u in [0, 1]).

    **Arguments:**
    - `experiment`: `"prbs"` (band-limited PRBS per channel between `levels`, holds of 3–15 s),
      `"step"` (all channels from `levels[0]` to `levels[1]` at a quarter of the run) or
      `"constant"` (the mean of `levels`).
    - `start`: `"steady"` (equilibrium at the mean input) or `"ambient"` (cold start).
    - `noise_std`: white measurement noise (°C), added to the `sensor_noise` effect if on.

    **Returns:** `IOData` with inputs `u_1..u_N` (+ `u_wall, u_plate, u_container`), outputs
    `y_1..y_N` (+ areas), `w_ambient` (the surroundings; the nominal constant unless
    `ambient_variation` has `measured=True`) and, with recoat cooling, `w_recoat` (1.0 at the
    sample a recoat starts). Same seed, same data.
    """
    if experiment not in ("prbs", "step", "constant"):
        raise ConfigError(f"generate: unknown experiment `{experiment}` (prbs, step, constant)")
    if start not in ("steady", "ambient"):
        raise ConfigError(f"generate: start must be 'steady' or 'ambient', got {start!r}")
    if not (isinstance(duration, (int, float)) and math.isfinite(duration) and duration >= 10 * printer.ts):
        raise ConfigError(f"generate: duration must be at least {10 * printer.ts:g} s, got {duration!r}")
    lo, hi = (float(levels[0]), float(levels[1]))
    if not (0.0 <= lo <= 1.0 and 0.0 <= hi <= 1.0):
        raise ConfigError(f"generate: levels must lie in [0, 1], got {levels!r}")
    if not (math.isfinite(noise_std) and noise_std >= 0):
        raise ConfigError(f"generate: noise_std must be >= 0, got {noise_std!r}")
    T = int(round(duration / printer.ts))
    nu = printer.n_inputs
    if experiment == "prbs":
        u = _prbs(seed, T, nu, (lo, hi))
    elif experiment == "step":
        u = np.full((T, nu), lo)
        u[T // 4:] = hi
    else:
        u = np.full((T, nu), 0.5 * (lo + hi))
    key = jax.random.key(int(seed))
    y, d = _generate_core(printer, jnp.asarray(u, printer.capacity.dtype), key,
                          0.5 * (lo + hi), noise_std, start == "steady")
    y = np.asarray(y)
    measured = printer.has("ambient_variation") and bool(printer.param("ambient_variation", "measured"))
    amb = np.asarray(d.ambient) if measured else np.full(T, float(printer.surroundings))
    w = [amb]
    wnames = ["ambient"]
    if printer.has("recoat_cooling"):
        w.append(np.asarray(d.recoat))
        wnames.append("recoat")
    names = input_names(printer)
    notes = (f"virtual printer: {printer.zones} zones, powder {printer.powder}, effects "
             f"{', '.join(printer.enabled) or 'none'}, experiment {experiment}, seed {seed}",)
    return from_arrays(u, y, printer.ts, np.stack(w, axis=1), input_names=names,
                       output_names=names, signal_names=tuple(wnames), notes=notes)
