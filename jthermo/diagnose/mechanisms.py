"""The mechanism library: grey-box augmentations of the bed model, all in one simulator.

The baseline is the thesis' bed model (eq. 3.5) in rate form, state $T$ (°C):

$$\\dot T_i = -a_i (T_i - T_s) + \\sum_j b_{ij} u_j, \\qquad a_i = G_i/C_i,\\; b_{ij} = n_{ij}/C_i .$$

Each mechanism adds states, terms or input transformations with physically constrained
(log-parametrised, hence positive) parameters:

| mechanism | augmentation |
| --- | --- |
| `lateral_conduction` | $+\\sum_{j} k_{ij}(T_j - T_i)$, $k_{ij} = k_{ji} \\ge 0$ for every pair of zones |
| `radiative_loss` | $-r_i\\,[(T_i + 273.15)^4 - (T_s + 273.15)^4]$ (kelvin), $r_i = \\varepsilon\\sigma A_i / C_i$ |
| `heat_accumulation` | a slow shared wall: $\\tau_w \\dot T_w = \\bar T - T_w + \\gamma (T_s - T_w)$, zones $+c_i (T_w - T_i)$ |
| `heater_lag` | lamps $\\tau_h \\dot p_j = u_j - p_j$ drive the zones instead of $u$ |
| `input_delay` | $u(t - d)$, $d$ whole samples (chosen on a grid, not by gradient) |
| `input_nonlinearity` | $u_j^{\\,e}$, $e > 0$ |
| `recoat_cooling` | a drop $\\delta_i \\ge 0$ of each zone at the detected recoat events (period, phase) |
| `ambient_variation` | $T_s(t) = \\bar T_s + $ the measured variation, or a piecewise-linear drift |

All mechanisms live in one simulator (`simulate`): a candidate model is a vector of 0/1
switches `on` (one per mechanism) plus a mask over the flat parameter vector, so every
candidate, and every combination, is fitted by one compiled, vmapped solver. The linear part
(zones, wall, lamps) is discretised exactly (zero-order hold); radiation enters through the
exponential-Euler integral of its rate over the sample.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

MECHANISMS = ("lateral_conduction", "radiative_loss", "heat_accumulation", "heater_lag",
              "input_delay", "input_nonlinearity", "recoat_cooling", "ambient_variation")
KELVIN = 273.15
RAD_SCALE = 1e-11          # 1/(s K^3): r_i = RAD_SCALE * exp(theta); εσA/C ≈ 1.4e-11 on PA12
DRIFT_SPACING = 300.0      # s between the knots of the piecewise-linear surroundings drift
UNROLL = 8                 # scan unrolling: per-step overhead dominates on CPU


@dataclasses.dataclass(frozen=True)
class Layout:
    """Where each parameter group sits in the flat vector θ (static: shapes only)."""

    n: int                   # zones
    nu: int                  # heaters
    n_drift: int             # drift knots
    sections: tuple          # ((name, start, size), ...)

    @property
    def size(self) -> int:
        return self.sections[-1][1] + self.sections[-1][2]

    def sl(self, name: str) -> slice:
        for nm, a, s in self.sections:
            if nm == name:
                return slice(a, a + s)
        raise KeyError(name)

    def mask(self, names) -> np.ndarray:
        m = np.zeros(self.size)
        for nm in names:
            m[self.sl(nm)] = 1.0
        return m


def make_layout(n: int, nu: int, n_drift: int) -> Layout:
    npair = n * (n - 1) // 2
    sizes = [("log_a", n), ("log_b", n * nu), ("x0", n), ("ts0", 1),
             ("log_k", max(npair, 1)), ("log_r", n), ("log_tauw", 1), ("log_gamma", 1),
             ("log_c", n), ("xw0", 1), ("log_tauh", 1), ("log_e", 1), ("log_drop", n),
             ("drift", n_drift)]
    out, a = [], 0
    for nm, s in sizes:
        out.append((nm, a, s))
        a += s
    return Layout(n, nu, n_drift, tuple(out))


#: parameter groups each mechanism adds (beyond the baseline's log_a, log_b, x0 [, ts0])
MECH_PARAMS = {
    "lateral_conduction": ("log_k",),
    "radiative_loss": ("log_r",),
    "heat_accumulation": ("log_tauw", "log_gamma", "log_c", "xw0"),
    "heater_lag": ("log_tauh",),
    "input_delay": (),
    "input_nonlinearity": ("log_e",),
    "recoat_cooling": ("log_drop",),
    "ambient_variation": ("drift",),
}
#: parameter groups re-estimated on each record (initial states, drift): not model physics
RECORD_PARAMS = ("x0", "xw0", "drift")


def drift_basis(T: int, ts: float, n_knots: int) -> np.ndarray:
    """Piecewise-linear hat functions with knots every `DRIFT_SPACING` s, `(T, n_knots)`;
    columns beyond the record's length are zero."""
    t = np.arange(T) * ts
    knots = np.arange(n_knots) * DRIFT_SPACING
    Phi = np.clip(1.0 - np.abs(t[:, None] - knots[None, :]) / DRIFT_SPACING, 0.0, None)
    Phi[:, knots > t[-1] + DRIFT_SPACING] = 0.0
    return Phi


def n_drift_knots(T: int, ts: float) -> int:
    return int(math.ceil(T * ts / DRIFT_SPACING)) + 1


def pairs(n: int):
    return [(i, j) for i in range(n) for j in range(i + 1, n)]


def _safe_pow(u, e):
    pos = u > 1e-12
    return jnp.where(pos, jnp.where(pos, u, 1.0) ** e, 0.0)


def simulate(theta, on, args, lay: Layout):
    """Simulated zone temperatures `(T, n)` °C of the augmented model.

    **Arguments:**
    - `theta`: flat parameters (see `make_layout`).
    - `on`: `(8,)` switches in the order of `MECHANISMS` (1.0 on, 0.0 off).
    - `args`: dict with `u (T, nu)`, `ts_level` (surroundings °C, scalar), `ts_free` (1.0 when
      the level is the fitted `ts0`), `wdev (T,)` measured surroundings variation, `Phi (T, K)`
      drift basis, `events (T, n)` recoat event flags, `delay` (int, samples), `u_pad (nu,)`
      the input before the record, `ts` (static float, in `lay` closure).
    """
    n, nu = lay.n, lay.nu
    g = lambda nm: theta[lay.sl(nm)]  # noqa: E731
    on_k, on_r, on_acc, on_lag, on_del, on_nl, on_rec, on_amb = [on[i] for i in range(8)]
    dt = theta.dtype
    a = jnp.exp(g("log_a"))
    b = jnp.exp(g("log_b")).reshape(n, nu)
    # surroundings: fixed level, or the fitted constant, plus the variation when switched on
    ts_level = args["ts_level"] + args["ts_free"] * g("ts0")[0]
    ts_seq = ts_level + on_amb * (args["wdev"] + args["Phi"] @ g("drift"))
    # inputs: dead time (dynamic shift), then the lamp nonlinearity
    u = args["u"]
    T = u.shape[0]
    d = (on_del * args["delay"]).astype(jnp.int32)
    upad = jnp.concatenate([jnp.broadcast_to(args["u_pad"], (16, nu)).astype(dt), u], axis=0)
    u = jax.lax.dynamic_slice(upad, (16 - d, jnp.zeros((), jnp.int32)), (T, nu))
    e = 1.0 + on_nl * (jnp.exp(g("log_e")[0]) - 1.0)
    u = _safe_pow(u, e)
    # linear continuous part, states z = [T (n), wall (1), lamps (nu)]
    nz = n + 1 + nu
    tauw = jnp.exp(g("log_tauw")[0])
    gam = jnp.exp(g("log_gamma")[0])
    c = on_acc * jnp.exp(g("log_c"))
    tauh = jnp.exp(g("log_tauh")[0])
    A = jnp.zeros((nz, nz), dt)
    iz = jnp.arange(n)
    A = A.at[iz, iz].set(-a - c)
    A = A.at[iz, n].set(c)
    A = A.at[n, iz].set(1.0 / (n * tauw))
    A = A.at[n, n].set(-(1.0 + gam) / tauw)
    if n > 1:
        pr = pairs(n)
        pi = jnp.array([p[0] for p in pr])
        pj = jnp.array([p[1] for p in pr])
        k = on_k * jnp.exp(g("log_k"))
        Lk = jnp.zeros((n, n), dt).at[pi, pj].add(k).at[pj, pi].add(k)
        Lk = Lk - jnp.diag(jnp.sum(Lk, axis=1))
        A = A.at[:n, :n].add(Lk)
    il = n + 1 + jnp.arange(nu)
    A = A.at[:n, n + 1:].set(on_lag * b)
    A = A.at[il, il].set(-1.0 / tauh)
    Bu = jnp.zeros((nz, nu), dt).at[:n].set((1.0 - on_lag) * b).at[il, jnp.arange(nu)].set(1.0 / tauh)
    bs = jnp.zeros((nz,), dt).at[:n].set(a).at[n].set(gam / tauw)
    # exact ZOH: E = e^{A h}, P1 = ∫ e^{A s} ds (Van Loan block exponential)
    M = jnp.zeros((2 * nz, 2 * nz), dt).at[:nz, :nz].set(A).at[:nz, nz:].set(jnp.eye(nz, dtype=dt))
    F = jax.scipy.linalg.expm(M * args["ts"])
    E, P1 = F[:nz, :nz], F[:nz, nz:]
    Bd = P1 @ Bu
    bsd = P1 @ bs
    Pz = P1[:, :n]
    r = on_r * RAD_SCALE * jnp.exp(g("log_r"))
    drop = on_rec * jnp.exp(g("log_drop"))
    lamp0 = args["u_pad"].astype(dt)
    z0 = jnp.concatenate([g("x0"), g("xw0") + ts_level, _safe_pow(lamp0, e)])

    def body(z, inp):
        uk, sk, ev = inp
        Tz = z[:n]
        q = -r * ((Tz + KELVIN) ** 4 - (sk + KELVIN) ** 4)
        zn = E @ z + Bd @ uk + bsd * sk + Pz @ q
        zn = zn.at[:n].add(-drop * ev)
        return zn, Tz

    _, ys = jax.lax.scan(body, z0, (u, ts_seq, args["events"]), unroll=UNROLL)
    return ys


def baseline_on() -> np.ndarray:
    return np.zeros(len(MECHANISMS))


def on_vector(mechs) -> np.ndarray:
    v = np.zeros(len(MECHANISMS))
    for m in mechs:
        v[MECHANISMS.index(m)] = 1.0
    return v


def initial_theta(lay: Layout, *, log_a, log_b, x0, ts0=0.0) -> np.ndarray:
    """A neutral start: the baseline parameters given, each mechanism at a plausible value."""
    th = np.zeros(lay.size)
    th[lay.sl("log_a")] = log_a
    th[lay.sl("log_b")] = np.ravel(log_b)
    th[lay.sl("x0")] = x0
    th[lay.sl("ts0")] = ts0
    a_mean = float(np.exp(np.mean(log_a)))
    th[lay.sl("log_k")] = np.log(0.1 * a_mean)
    th[lay.sl("log_r")] = np.log(0.5)
    th[lay.sl("log_tauw")] = np.log(1000.0)
    th[lay.sl("log_gamma")] = np.log(0.5)
    th[lay.sl("log_c")] = np.log(0.3 * a_mean)
    th[lay.sl("xw0")] = 0.0
    th[lay.sl("log_tauh")] = np.log(5.0)
    th[lay.sl("log_e")] = 0.0
    th[lay.sl("log_drop")] = np.log(0.5)
    th[lay.sl("drift")] = 0.0
    return th


def physical_parameters(theta, mech: str, lay: Layout, ts: float, extra: dict) -> dict:
    """The physical figures a mechanism's fitted parameters stand for (JSON-ready)."""
    th = np.asarray(theta)
    g = lambda nm: th[lay.sl(nm)]  # noqa: E731
    if mech == "lateral_conduction":
        k = np.exp(g("log_k"))
        pr = pairs(lay.n)
        top = np.argsort(k)[::-1][: min(len(pr), 2 * lay.n)]
        return {"rate_per_s": {f"{pr[i][0] + 1}-{pr[i][1] + 1}": float(k[i]) for i in top},
                "mean_neighbour_rate_per_s": float(np.mean(np.sort(k)[::-1][:max(lay.n - 1, 1)])),
                "relative_to_loss": float(np.mean(np.sort(k)[::-1][:max(lay.n - 1, 1)])
                                          / np.mean(np.exp(g("log_a"))))}
    if mech == "radiative_loss":
        r = RAD_SCALE * np.exp(g("log_r"))
        tl = extra.get("ts_level", 20.0)
        tm = extra.get("t_mean", tl)
        lin = 4 * r * (tm + KELVIN) ** 3
        return {"coefficient_per_s_K3": [float(v) for v in r],
                "linearised_rate_per_s": float(np.mean(lin)),
                "share_of_loss": float(np.mean(lin / (lin + np.exp(g("log_a")))))}
    if mech == "heat_accumulation":
        tauw = float(np.exp(g("log_tauw")[0]))
        gam = float(np.exp(g("log_gamma")[0]))
        c = np.exp(g("log_c"))
        return {"time_constant_s": tauw / (1.0 + gam),
                "share": float(np.mean(c / (c + np.exp(g("log_a")))))}
    if mech == "heater_lag":
        return {"time_constant_s": float(np.exp(g("log_tauh")[0]))}
    if mech == "input_delay":
        return {"delay_s": float(extra.get("delay", 0) * ts)}
    if mech == "input_nonlinearity":
        return {"exponent": float(np.exp(g("log_e")[0]))}
    if mech == "recoat_cooling":
        drops = np.exp(g("log_drop"))
        return {"period_s": float(extra.get("period_s", float("nan"))),
                "drop_C": float(np.mean(drops)), "drop_per_zone_C": [float(v) for v in drops],
                "phase_s": float(extra.get("phase_s", float("nan")))}
    if mech == "ambient_variation":
        d = g("drift")
        if extra.get("measured_ambient", False):
            return {"source": "measured w_ambient", "range_C": float(extra.get("w_range", 0.0))}
        return {"source": "estimated drift", "range_C": float(np.ptp(d)) if d.size else 0.0}
    raise KeyError(mech)
