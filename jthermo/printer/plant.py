"""The virtual printer as a plant: its continuous-time model, its exact discretisation
(`Printer.discretise`, a `DiscretePrinter` of `printer.discrete`) and steady states; its state
and disturbances are `printer.state`'s (see `jthermo.printer` for the physics)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ModelError
from .discrete import DiscretePrinter
from .effects import EFFECTS
from .geometry import KELVIN, NOMINAL_INPUT, SIGMA, grid_edges, grid_positions, grid_shape
from .integration import phi_matrices
from .noise import NoiseStream
from .state import PrinterDisturbance, PrinterState

#: sub-steps per sample for radiation alone (no recoat sweep): its T^4 term changes little over
#: a sample, so one ETD2RK step stays within 1e-3 °C of 100 sub-steps in closed loop
#: (measured by `python benchmarks/simulate_substeps.py`; the sensor noise is 0.05-0.1 °C)
SMOOTH_SUBSTEPS = 1


def _safe_power(u, p):
    pos = u > 0
    return jnp.where(pos, jnp.where(pos, u, 1.0) ** p, 0.0)


# ----------------------------------------------------------------------------- the printer


class Printer(eqx.Module):
    """The virtual printer (see `jthermo.printer`). Build it with `make_printer`.

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
    window: Float[Array, " 2"]                # °C print window (a leaf: powders share programs)
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

    def _nonlinear(self, z, t, ambient, recoat: bool = True):
        """Radiation and recoat terms on the zone rows at time `t` s since the recoat start
        (`recoat=False`: radiation only, for runs without a recoat sweep)."""
        n = self.zones
        T = z[:n]
        f = jnp.zeros_like(z)
        if self.has("radiative_loss"):
            p = self.effects["radiative_loss"]
            q = p["emissivity"] * SIGMA * p["area_m2"] * ((T + KELVIN) ** 4 - (ambient + KELVIN) ** 4)
            f = f.at[:n].add(-q / self.capacity)
        if recoat and self.has("recoat_cooling"):
            p = self.effects["recoat_cooling"]
            _, cols = self.grid
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
    def window_centre(self) -> Float[Array, ""]:
        return 0.5 * (self.window[0] + self.window[1])

    def _power(self, u):
        """Heater power fractions after the lamp nonlinearity (bed heaters only)."""
        if self.has("input_nonlinearity"):
            e = self.effects["input_nonlinearity"]["exponent"]
            n = self.zones
            # power ∝ u^e, normalised to equal u at the nominal input
            return u.at[:n].set(NOMINAL_INPUT ** (1.0 - e) * _safe_power(u[:n], e))
        return u

    def discretise(self, recoat: bool = True) -> DiscretePrinter:
        """Precompute the sample-time matrices once (what `closedloop.simulate` calls).

        `recoat=False` is for a run in which no recoat sweep acts (no recoat flag and none in
        progress, as in the tracking and preheat scenarios): the sweep term is left out, and
        radiation, smooth over a sample, takes `SMOOTH_SUBSTEPS` sub-step(s) instead of
        `substeps` (the sweep's columns switch within a sample and need them)."""
        A, Bp, bs, Bl = self.linear_system()
        if not self.nonlinear:
            m = 1
        elif recoat:
            m = self.substeps
        else:
            m = min(self.substeps, SMOOTH_SUBSTEPS) if self.has("radiative_loss") else 1
        return DiscretePrinter(printer=self, disc=phi_matrices(A, self.ts / m), Bp=Bp, bs=bs,
                               Bl=Bl, m=m, recoat=recoat)

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

    def noise_stream(self, key, white_std: float = 0.0) -> NoiseStream:
        """The noise of `sample_noise(key, T, white_std)` drawn one sample at a time inside a
        scan (`NoiseStream.at`): the same distribution per channel (std, AR(1) autocorrelation),
        other draws (fused white parts, float32 normals: `printer.noise`), no `(T, ny)` array."""
        sensor = self.effects["sensor_noise"] if self.has("sensor_noise") else None
        return NoiseStream(key=key, white_std=float(white_std), sensor=sensor,
                           ny=self.n_outputs, zones=self.zones,
                           dtype=jnp.dtype(self.capacity.dtype).name)


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
