"""The mechanism library: grey-box augmentations of the bed model, all in one simulator.

The baseline is the thesis' bed model (eq. 3.5) in rate form, state $T$ (°C):

$$\\dot T_i = -a_i (T_i - T_s) + \\sum_j b_{ij} u_j, \\qquad a_i = G_i/C_i,\\; b_{ij} = n_{ij}/C_i .$$

Each mechanism adds states, terms or input transformations with physically constrained
(log-parametrised, hence positive) parameters:

| mechanism | augmentation |
| --- | --- |
| `lateral_conduction` | $+\\sum_{j} k_{ij}(T_j - T_i)$, $k_{ij} = k_{ji} \\ge 0$ for every pair of zones |
| `radiative_loss` | $-r_i\\,[(T_i + 273.15)^4 - (T_s + 273.15)^4]$ (kelvin), $r_i = \\varepsilon\\sigma A_i / C_i$, set by its share of the tangent loss (`loss_split`; a share above 1 is a loss steeper than radiation alone: convection $h(T)$) |
| `heat_accumulation` | a slow shared wall: $\\tau_w \\dot T_w = \\bar T - T_w + \\gamma (T_s - T_w)$, zones $+c_i (T_w - T_i)$; $\\tau_w > 200$ s, $0 < \\gamma < 4$ |
| `heater_lag` | lamps $\\tau_h \\dot p_j = u_j - p_j$ drive the zones instead of $u$ |
| `input_delay` | $u(t - d)$, $d$ in seconds, any fraction of a sample: the held input is interpolated between the two samples around $t - d$; $d$ moves within one sample of the delay scan's best (by gradient) |
| `input_nonlinearity` | $u_j^{\\,e}$, $e > 0$ |
| `recoat_cooling` | a drop $\\delta_i \\ge 0$ of each zone at the detected recoat events (period and phase, or drops at any times: `events.py`) |
| `ambient_variation` | $T_s(t) = \\bar T_s + $ the measured variation, or a piecewise-linear drift |

All mechanisms live in one simulator: a candidate is a vector of 0/1 switches `on` (one per
mechanism) plus a mask over one flat parameter vector, so every candidate and combination is
fitted by one compiled, vmapped solver. Fitting is per zone (`simulate_zone`, series-parallel
form: a zone's neighbours and the bed's mean temperature enter as their measured values, the
zone itself is simulated), which makes every zone and candidate a small independent problem;
`simulate_full` then couples the fitted zone models (neighbours simulated) for validation.
Candidates start from the baseline, every heater gain alive (`live_gains`).
The linear part (zone, wall, lamp) is discretised exactly (zero-order hold), so the lamp model
tends to the lag-free one as τ_h → 0; radiation enters through the exponential-Euler integral
of its rate over the sample.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .recurrence import radiative

MECHANISMS = ("lateral_conduction", "radiative_loss", "heat_accumulation", "heater_lag",
              "input_delay", "input_nonlinearity", "recoat_cooling", "ambient_variation")
KELVIN = 273.15
DRIFT_SPACING = 300.0      # s between the knots of the piecewise-linear surroundings drift
UNROLL = 1                 # scan unrolling: per-step overhead dominates on CPU
#: samples of input history kept before the record (the longest dead time tried, plus two)
PAD = 42


@dataclasses.dataclass(frozen=True)
class Layout:
    """Where each parameter group of one zone's model sits in its flat vector θ (static)."""

    n: int                   # zones
    nu: int                  # heaters
    n_drift: int             # drift knots (of every estimation record: `pool.drift_basis`)
    sections: tuple          # ((name, start, size), ...)
    records: tuple = ()      # samples of each pooled estimation record (`pool.py`); () one record

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


def make_layout(n: int, nu: int, n_drift: int, records: tuple = ()) -> Layout:
    """Per-zone parameter layout: zone i's model is fitted on its own (its neighbours enter
    through their measured temperatures), so every zone has the same vector. With pooled
    `records` (their lengths), the second and later records' initial states and level offsets
    follow (`*_rec`, one entry per record after the first; empty for one record)."""
    more = max(len(records) - 1, 0)
    sizes = [("log_a", 1), ("log_b", nu), ("x0", 1), ("ts0", 1), ("log_k", max(n - 1, 1)),
             ("rad_share", 1), ("log_tauw", 1), ("log_gamma", 1), ("log_c", 1), ("xw0", 1),
             ("log_tauh", 1), ("log_e", 1), ("log_drop", 1), ("dfrac", 1), ("drift", n_drift),
             ("x0_rec", more), ("ts0_rec", more), ("xw0_rec", more)]
    out, a = [], 0
    for nm, s in sizes:
        out.append((nm, a, s))
        a += s
    return Layout(n, nu, n_drift, tuple(out), tuple(int(t) for t in records) if more else ())


#: parameter groups each mechanism adds (beyond the baseline's log_a, log_b, x0 [, ts0])
MECH_PARAMS = {
    "lateral_conduction": ("log_k",),
    "radiative_loss": ("rad_share",),
    "heat_accumulation": ("log_tauw", "log_gamma", "log_c", "xw0", "xw0_rec"),
    "heater_lag": ("log_tauh",),
    "input_delay": ("dfrac",),
    "input_nonlinearity": ("log_e",),
    "recoat_cooling": ("log_drop",),
    "ambient_variation": ("drift",),
}


def n_added_per_zone(mech: str, lay) -> int:
    """Parameters `mech` adds to one zone's baseline problem (sizes of its `MECH_PARAMS`)."""
    return sum(lay.sl(g).stop - lay.sl(g).start for g in MECH_PARAMS.get(mech, ()))


def n_added(mech: str, lay, shared_drift: bool) -> int:
    """Parameters `mech` adds to the `lay.n`-zone model, the degrees of freedom of its tests:
    its `MECH_PARAMS` in every zone, but a surroundings drift shared by every zone (unmeasured
    surroundings are one temperature: `commondrift.common_drift_fit`, the joint fits' record drift)
    only its `lay.n_drift` knots."""
    if mech == "ambient_variation" and shared_drift:
        return lay.n_drift
    return n_added_per_zone(mech, lay) * lay.n


def drift_basis(T: int, ts: float, n_knots: int) -> np.ndarray:
    """Piecewise-linear hat functions with knots every `DRIFT_SPACING` s, `(T, n_knots)`;
    knots beyond the record's end get zero columns."""
    t = np.arange(T) * ts
    knots = np.arange(n_knots) * DRIFT_SPACING
    Phi = np.clip(1.0 - np.abs(t[:, None] - knots[None, :]) / DRIFT_SPACING, 0.0, None)
    return Phi


def n_drift_knots(T: int, ts: float) -> int:
    return math.ceil((T - 1) * ts / DRIFT_SPACING) + 1


#: the wall is a slow body: its time constant τ_w is at least this (s) ...
TAUW_MIN = 200.0
#: ... and its own loss to the surroundings at most this multiple of its coupling to the bed,
#: so the effective time constant τ_w / (1 + γ) stays above TAUW_MIN / (1 + GAMMA_MAX) = 40 s
GAMMA_MAX = 4.0


def wall_parameters(log_tauw, log_gamma):
    """(τ_w in s, γ) from their unconstrained parameters: τ_w > TAUW_MIN, 0 < γ < GAMMA_MAX."""
    xp = jnp if isinstance(log_tauw, jax.Array) else np
    return TAUW_MIN + xp.exp(log_tauw), GAMMA_MAX / (1.0 + xp.exp(-log_gamma))


#: the lamp time constant is at least this (s): keeps the lamp's rate finite as τ_h → 0, where
#: the lamp model tends to the lag-free one
TAUH_MIN = 0.05


def lamp_tau(log_tauh):
    """Lamp time constant τ_h (s) from its unconstrained parameter: τ_h > TAUH_MIN."""
    xp = jnp if isinstance(log_tauh, jax.Array) else np
    return TAUH_MIN + xp.exp(log_tauh)


def zoh_blocks(A, Bc, ts, squarings: int = 10, order: int = 10):
    """Exact zero-order-hold matrices of $\\dot s = A s + B_c w$: $(E, B_d, P_1)$ with
    $E = e^{A t_s}$ and $P_1 = \\int_0^{t_s} e^{A\\tau} d\\tau$ (what a rate held over the sample adds).

    Both are the top blocks of $e^{M t_s}$, $M = \\begin{pmatrix} A & I \\\\ 0 & 0 \\end{pmatrix}$, by
    a fixed Taylor series and squaring (branch-free: cheap to compile and vmap; accurate to
    round-off for $\\|A t_s\\| \\lesssim 100$), written on the $m \\times m$ blocks (the bottom
    rows stay $(0, I)$): with $h = t_s / 2^s$, $X = A h$,
    $E_h = \\sum_{k=0}^{K} X^k / k!$, $P_h = h \\sum_{k=1}^{K} X^{k-1} / k!$, then $s$ times
    $(E, P) \\leftarrow (E^2, E P + P)$. A quarter of the dense $2m \\times 2m$ products, and of
    their tangents in the fits' forward-mode Jacobians."""
    m = A.shape[0]
    h = ts / (2.0 ** squarings)
    X = A * h
    eye = jnp.eye(m, dtype=A.dtype)
    term, E, P = eye, eye, jnp.zeros_like(A)
    for k in range(1, order + 1):
        P = P + term * h / k
        term = term @ X / k
        E = E + term
    for _ in range(squarings):
        E, P = E @ E, E @ P + P
    return E, P @ Bc, P


def _safe_pow(u, e):
    pos = u > 1e-12
    return jnp.where(pos, jnp.where(pos, u, 1.0) ** e, 0.0)


def delay_samples(delay, dfrac):
    """Dead time in samples: within one sample of the scan's `delay` (samples, may be
    fractional), moved by the unconstrained `dfrac`; never negative."""
    xp = jnp if isinstance(dfrac, jax.Array) else np
    return xp.clip(delay + 2.0 / (1.0 + xp.exp(-dfrac)) - 1.0, 0.0, PAD - 2.0)


def delayed_inputs(theta, on, u, u_pad, delay, lay):
    """Heater inputs after dead time and lamp nonlinearity: `(T, nu)` per zone model, and the
    (transformed) input before the record `(nu,)`.

    A dead time of $d = i + f$ samples ($0 \\le f < 1$) gives the input
    $(1 - f)\\,u_{k-i} + f\\,u_{k-i-1}$: the held input's share of the sample that is still the
    older value, continuous (and differentiable almost everywhere) in $d$."""
    g = lambda nm: theta[lay.sl(nm)]
    nu = lay.nu
    T = u.shape[0]
    dt = theta.dtype
    d = on[4] * delay_samples(jnp.asarray(delay, dt), g("dfrac")[0])
    i = jnp.floor(d)
    f = d - i
    i = i.astype(jnp.int32)
    upad = jnp.concatenate([jnp.broadcast_to(u_pad, (PAD, nu)).astype(dt), u.astype(dt)], axis=0)
    zero = jnp.zeros((), jnp.int32)
    u = ((1.0 - f) * jax.lax.dynamic_slice(upad, (PAD - i, zero), (T, nu))
         + f * jax.lax.dynamic_slice(upad, (PAD - i - 1, zero), (T, nu)))
    e = 1.0 + on[5] * (jnp.exp(g("log_e")[0]) - 1.0)
    return _safe_pow(u, e), _safe_pow(u_pad.astype(dt), e)


#: the temperature-dependent loss's largest share of the tangent loss rate. Its curvature
#: $\\kappa = 3\\rho/T_K$ then reaches $12/T_K \\approx 1/(25\\dots 28)$ per K at 300-330 K: the
#: curvature of a natural-convection loss $c\\Delta^{4/3}$ ($\\kappa = 1/(3\\Delta)$) at rises down to
#: about 9 K, where a share of 1 (radiation alone) reaches it only down to about 35 K
RAD_SHARE_MAX = 4.0
def share_parameter(share: float) -> float:
    """The unconstrained parameter of a radiative share in (0, `RAD_SHARE_MAX`) (`loss_split`)."""
    return -math.log(RAD_SHARE_MAX / share - 1.0)


#: the unconstrained parameter that starts the share at 0.5 (radiation half of the tangent loss)
RAD_SHARE_START = share_parameter(0.5)


def loss_split(log_a, rad_share, on_rad, t_ref):
    """(linear loss rate $a_{lin}$ in 1/s, radiative coefficient $r$ in 1/(s K³)) of a zone.

    The $T^4$ term is parametrised by its share $\\rho = \\rho_{max}\\,\\mathrm{sigmoid}(\\theta)$
    of the *tangent* loss rate $e^{\\log a}$ at the reference temperature `t_ref` (°C, the
    record's mean): $a_{lin} = (1 - \\rho) e^{\\log a}$, $4 r (T_{ref} + 273.15)^3 = \\rho e^{\\log a}$.
    Moving $\\rho$ keeps the small-signal dynamics and changes only the loss's curvature
    $\\kappa = L''/L' = 3\\rho / T_K$ and level, which makes the fit well conditioned (a raw
    coefficient trades with $a$ along a curved valley). $\\rho \\le 1$ is radiation beside a
    linear loss; $1 < \\rho \\le$ `RAD_SHARE_MAX` ($a_{lin} < 0$) is a loss steeper than
    radiation alone, as natural convection's $h \\propto \\Delta^{1/4 \\dots 1/3}$ gives
    ($\\kappa = (1/4 \\dots 1/3)/\\Delta$, see `RAD_SHARE_MAX`)."""
    xp = jnp if isinstance(log_a, jax.Array) else np
    a = xp.exp(log_a)
    rho = on_rad * RAD_SHARE_MAX / (1.0 + xp.exp(-rad_share))
    return a * (1.0 - rho), rho * a / (4.0 * (t_ref + KELVIN) ** 3)


def _zone_matrices(theta, on, lay, ts, a_lin):
    """Continuous 3-state (zone, wall, lamp) model of one zone and its exact ZOH matrices.

    Inputs per sample: [heater heat rate v, surroundings Ts, Σ_j k_j T_j, mean zone T]. The lamp
    state follows v with lag τ_h; the zone sees the lamp (lag on) or v itself (lag off). The zone
    loses heat at the whole tangent rate $a$ (radiation's tangent at `t_ref` included, so that
    it is discretised exactly too); the surroundings enter through the linear part $a_{lin}$."""
    g = lambda nm: theta[lay.sl(nm)]
    dt = theta.dtype
    a = jnp.exp(g("log_a")[0])
    ksum = on[0] * jnp.sum(jnp.exp(g("log_k")))
    c = on[2] * jnp.exp(g("log_c")[0])
    tauw, gam = wall_parameters(g("log_tauw")[0], g("log_gamma")[0])
    lag = on[3]
    ih = 1.0 / jnp.where(lag > 0, lamp_tau(g("log_tauh")[0]), 1.0)
    z = jnp.zeros((), dt)
    A = jnp.stack([jnp.stack([-(a + ksum + c), c, lag + z]),
                   jnp.stack([z, -(1.0 + gam) / tauw, z]),
                   jnp.stack([z, z, -ih])])
    Bc = jnp.stack([jnp.stack([1.0 - lag + z, a_lin, 1.0 + z, z]),
                    jnp.stack([z, gam / tauw, z, 1.0 / tauw]),
                    jnp.stack([ih, z, z, z])])
    E, Bd, P1 = zoh_blocks(A, Bc, ts)
    return E, Bd, P1[:, 0]


def simulate_zone(theta, on, z, lay: Layout):
    """Simulated temperature `(T,)` °C of one zone's augmented model (series-parallel form:
    the neighbours' and the bed's mean temperatures are the measured ones).

    **Arguments:**
    - `theta`: this zone's flat parameters (see `make_layout`); `on`: `(8,)` switches in the
      order of `MECHANISMS`.
    - `z`: dict with `u (T, nu)`, `ynb (T, n-1)` the other zones' measured temperatures,
      `ybar (T,)` the mean measured zone temperature, `events (T,)` recoat flags of this zone,
      `ts_level`, `ts_free`, `wdev (T,)`, `Phi (T, K)`, `delay`, `u_pad (nu,)`, `ts`, `t_ref`.
    """
    g = lambda nm: theta[lay.sl(nm)]
    ts_level = z["ts_level"] + z["ts_free"] * g("ts0")[0]
    # the drift has no mean on the estimation record: a constant offset would trade with the
    # heater gains and make each zone's drift a different, meaningless level
    dr = g("drift") - jnp.mean(g("drift"))
    ts_seq = ts_level + on[7] * (z["wdev"] + z["Phi"] @ dr)
    u, u0 = delayed_inputs(theta, on, z["u"], z["u_pad"], z["delay"], lay)
    b = jnp.exp(g("log_b"))
    v = u @ b
    nb = on[0] * (z["ynb"] @ jnp.exp(g("log_k"))[: z["ynb"].shape[1]])
    a_lin, r = loss_split(g("log_a")[0], g("rad_share")[0], on[1], z["t_ref"])
    a_rad = jnp.exp(g("log_a")[0]) - a_lin           # radiation's tangent rate at t_ref
    E, Bd, pz = _zone_matrices(theta, on, lay, z["ts"], a_lin)
    drop = on[6] * jnp.exp(g("log_drop")[0])
    # everything that does not depend on the state is computed here, outside the scan: the
    # scan body is a handful of scalar multiply-adds (per-step overhead dominates on CPU)
    W = jnp.stack([v, ts_seq, nb, z["ybar"]], axis=1)
    Fz = W @ Bd.T
    Fz = Fz.at[:, 0].add(-drop * z["events"])
    sk4 = (ts_seq + KELVIN) ** 4
    s0 = jnp.stack([g("x0")[0], g("xw0")[0] + ts_level, u0 @ b])

    def body(s, inp):
        fk, s4 = inp
        # radiation beyond its tangent (which the exact linear part already carries)
        q = a_rad * s[0] - r * ((s[0] + KELVIN) ** 4 - s4)
        sn = E[:, 0] * s[0] + E[:, 1] * s[1] + E[:, 2] * s[2] + fk + pz * q
        return sn, s[0]

    _, ys = jax.lax.scan(body, s0, (Fz, sk4), unroll=UNROLL)
    return ys


def simulate_full(Theta, on, f, lay: Layout, rec):
    """Coupled simulation `(T, n)` of all zones' fitted models (neighbours simulated, not
    measured): what the validation fit uses.

    `Theta (n, P)` per-zone parameters; `rec` = [x0 (n), wall0 (n), drift (Kv)[, level]] the
    record's own initial states (°C), surroundings drift and (optional, used where the
    surroundings are not measured: `ts_free`) the record's own surroundings level offset (°C); `f`
    dict with `u`, `events (T, n)`, `ts_level`, `ts_free`, `wdev`, `Phi (T, Kv)`, `delay`, `u_pad`,
    `ts`, `t_ref`. The lamps start at their steady state for `u_pad`.

    Where the level is free, zone $i$ sees $T_{s,i} = $ `ts_level` $+ \\theta_{ts0,i} + $ `level`:
    its own fitted offset (as in its per-zone fit, where the offset trades with its gains and
    loss) plus the record's common one. (A single shared level, the median of the zones'
    offsets, gave multi-zone baselines validation fits of -12 ... -271 %.)
    """
    n = lay.n
    dt = Theta.dtype
    kv = f["Phi"].shape[1]
    x0, w0, dr = rec[:n], rec[n:2 * n], rec[2 * n:2 * n + kv]
    lev = rec[2 * n + kv] if rec.shape[0] > 2 * n + kv else 0.0
    g = lambda nm: Theta[:, lay.sl(nm)]
    ts_level = f["ts_level"] + f["ts_free"] * (g("ts0")[:, 0] + lev)            # (n,)
    ts_seq = ts_level[None, :] + on[7] * (f["wdev"] + f["Phi"] @ dr)[:, None]    # (T, n)

    def zone_input(th):
        u, u0 = delayed_inputs(th, on, f["u"], f["u_pad"], f["delay"], lay)
        b = jnp.exp(th[lay.sl("log_b")])
        return u @ b, u0 @ b

    V, p0 = jax.vmap(zone_input, out_axes=(1, 0))(Theta)           # (T, n), (n,)
    a_lin, r = loss_split(g("log_a")[:, 0], g("rad_share")[:, 0], on[1], f["t_ref"])
    a = jnp.exp(g("log_a")[:, 0])
    a_rad = a - a_lin
    c = on[2] * jnp.exp(g("log_c")[:, 0])
    tauw, gam = wall_parameters(g("log_tauw")[:, 0], g("log_gamma")[:, 0])
    lag = on[3]
    ih = 1.0 / jnp.where(lag > 0, lamp_tau(g("log_tauh")[:, 0]), 1.0)
    kk = on[0] * jnp.exp(g("log_k"))                             # (n, n-1): row i, others
    K = jnp.zeros((n, n), dt)
    if n > 1:
        cols = np.array([[j for j in range(n) if j != i] for i in range(n)])
        K = K.at[np.repeat(np.arange(n), n - 1), cols.ravel()].set(kk[:, : n - 1].ravel())
    iz = jnp.arange(n)
    A = jnp.zeros((3 * n, 3 * n), dt)
    A = A.at[:n, :n].set(K - jnp.diag(a + jnp.sum(K, axis=1) + c))
    A = A.at[iz, n + iz].set(c)
    A = A.at[iz, 2 * n + iz].set(lag)
    A = A.at[n:2 * n, :n].set(jnp.broadcast_to((1.0 / (n * tauw))[:, None], (n, n)))
    A = A.at[n + iz, n + iz].set(-(1.0 + gam) / tauw)
    A = A.at[2 * n + iz, 2 * n + iz].set(-ih)
    Bc = jnp.zeros((3 * n, 2 * n), dt)            # inputs: heat rates (n), surroundings (n)
    Bc = Bc.at[iz, iz].set(1.0 - lag).at[iz, n + iz].set(a_lin).at[n + iz, n + iz].set(gam / tauw)
    Bc = Bc.at[2 * n + iz, iz].set(ih)
    E, Bd, P1 = zoh_blocks(A, Bc, f["ts"])
    Pz = P1[:, :n]
    drop = on[6] * jnp.exp(g("log_drop")[:, 0])
    Fz = jnp.concatenate([V, ts_seq], axis=1) @ Bd.T
    Fz = Fz.at[:, :n].add(-drop[None, :] * f["events"])
    sk4 = (ts_seq + KELVIN) ** 4
    s0 = jnp.concatenate([x0, w0, p0])

    # the scan, with a forward-mode derivative that batches the tangents: `recurrence.radiative`
    return radiative(E, Pz, a_rad, r, Fz, sk4, s0)


def baseline_on() -> np.ndarray:
    return np.zeros(len(MECHANISMS))


def on_vector(mechs) -> np.ndarray:
    v = np.zeros(len(MECHANISMS))
    for m in mechs:
        v[MECHANISMS.index(m)] = 1.0
    return v


#: a heater gain starts at this share of the zone's largest at least (`live_gains`)
GAIN_START_SHARE = 0.02


def live_gains(log_b) -> np.ndarray:
    """One zone's log heater gains `(nu,)`, each at least `GAIN_START_SHARE` of the largest: a gain
    the baseline left at its bound ($10^{-12}$ of the largest) has no gradient in the log
    parametrisation: such gains hold a zone's lamp fit on a plateau, unconverged at `N_ITER`."""
    lb = np.asarray(log_b, float).ravel()
    return np.maximum(lb, np.max(lb) + math.log(GAIN_START_SHARE))


def initial_theta(lay: Layout, *, log_a, log_b, x0, ts0=0.0, xw0=0.0) -> np.ndarray:
    """One zone's start: the baseline parameters given (dead heater gains revived, `live_gains`),
    each mechanism at a plausible value."""
    th = np.zeros(lay.size)
    th[lay.sl("log_a")] = log_a
    th[lay.sl("log_b")] = live_gains(log_b)
    th[lay.sl("x0")] = x0
    th[lay.sl("ts0")] = ts0
    a = float(np.exp(log_a))
    th[lay.sl("log_k")] = np.log(0.05 * a)
    th[lay.sl("rad_share")] = RAD_SHARE_START              # half of the loss
    th[lay.sl("log_tauw")] = np.log(1000.0 - TAUW_MIN)
    th[lay.sl("log_gamma")] = np.log(1.0 / (GAMMA_MAX - 1.0))      # γ = 1
    th[lay.sl("log_c")] = np.log(0.3 * a)
    th[lay.sl("xw0")] = xw0
    th[lay.sl("log_tauh")] = np.log(5.0)
    th[lay.sl("log_e")] = 0.0
    th[lay.sl("log_drop")] = np.log(0.3)
    th[lay.sl("dfrac")] = 0.0                              # the delay scan's best
    th[lay.sl("drift")] = 0.0
    return th


def physical_parameters(Theta, mech: str, lay: Layout, ts: float, extra: dict) -> dict:
    """The physical figures a mechanism's fitted per-zone parameters stand for (JSON-ready)."""
    th = np.asarray(Theta)
    g = lambda nm: th[:, lay.sl(nm)]
    med = lambda v: float(np.median(v))
    if mech == "lateral_conduction":
        if lay.n < 2:
            return {}
        k = np.exp(g("log_k"))[:, : lay.n - 1]
        a = np.exp(g("log_a")[:, 0])
        strongest = {}
        for i in range(lay.n):
            others = [j for j in range(lay.n) if j != i]
            jj = int(np.argmax(k[i]))
            strongest[str(i + 1)] = {"neighbour": others[jj] + 1, "rate_per_s": float(k[i, jj])}
        return {"strongest_neighbour": strongest,
                "coupling_to_loss_ratio": float(np.median(np.max(k, axis=1) / a))}
    if mech == "radiative_loss":
        tm = extra.get("t_mean", 20.0)
        _, r = loss_split(g("log_a")[:, 0], g("rad_share")[:, 0], 1.0, tm)
        share = RAD_SHARE_MAX / (1.0 + np.exp(-g("rad_share")[:, 0]))
        curv = 3.0 * share / (tm + KELVIN)
        return {"coefficient_per_s_K3": [float(v) for v in r], "share_of_loss": med(share),
                "curvature_per_K": med(curv), "steeper_than_radiation": bool(med(share) > 1.0)}
    if mech == "heat_accumulation":
        tauw, gam = wall_parameters(g("log_tauw")[:, 0], g("log_gamma")[:, 0])
        c = np.exp(g("log_c")[:, 0])
        a = np.exp(g("log_a")[:, 0])
        return {"time_constant_s": med(tauw / (1.0 + gam)), "share": med(c / (c + a))}
    if mech == "heater_lag":
        return {"time_constant_s": med(lamp_tau(g("log_tauh")[:, 0]))}
    if mech == "input_delay":
        d = delay_samples(float(extra.get("delay", 0.0)), g("dfrac")[:, 0])
        return {"delay_s": med(d * ts), "delay_per_zone_s": [float(v * ts) for v in d]}
    if mech == "input_nonlinearity":
        return {"exponent": med(np.exp(g("log_e")[:, 0]))}
    if mech == "recoat_cooling":
        drops = np.exp(g("log_drop")[:, 0])
        out = {"period_s": float(extra.get("period_s", float("nan"))), "drop_C": med(drops),
               "drop_per_zone_C": [float(v) for v in drops]}
        times = extra.get("recoat_times_s")
        if times:                   # drops at irregular times (`events.detect_drops`): the period
            # is the events' median spacing (theirs where they are periodic), `spacing_cv` says how
            # far from periodic they are
            gaps = np.diff(times) if len(times) > 1 else np.array([np.nan])
            out.update(period_s=float(np.median(gaps)), events=len(times), mean_interval_s=float(np.mean(gaps)),
                       spacing_cv=float(np.std(gaps) / np.mean(gaps)),
                       event_times_s=[round(float(t), 3) for t in times])
        return out
    if mech == "ambient_variation":
        if extra.get("measured_ambient", False):
            return {"source": "measured surroundings signal", "range_C": float(extra.get("w_range", 0.0))}
        d = np.median(g("drift"), axis=0)
        return {"source": "estimated surroundings drift", "range_C": float(np.ptp(d)) if d.size else 0.0}
    raise KeyError(mech)
