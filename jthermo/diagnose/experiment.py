"""The experiment that separates rival explanations: an input designed by gradient.

When the diagnosis leaves explanations within its test's resolution (a finding's `rivals`),
their fitted models predict the records at hand about equally well. The next record should be
one on which they disagree most, relative to the noise. For two models $a$, $b$ (fitted on
the estimation record, `select.diagnose`'s single-mechanism refits) and an input sequence $u$,

$$S_{ab}(u) = \\sum_i \\frac{\\|(I - \\Pi_N)\\,(\\hat y_{a,i}(u) - \\hat y_{b,i}(u))\\|^2}{\\sigma_i^2},$$

the expected log-likelihood gap per record between the two explanations under white noise of
variance $\\sigma_i^2$ (the top model's validation residual power, zone $i$), after removing
what the nuisance parameters re-estimated on a new record can absorb. $\\Pi_N$ projects onto
the span of both models' sensitivities to exactly what the diagnosis re-estimates on a record
it validates on (`nuisance_jacobians`): every zone's initial state, a body's initial state, the
surroundings level where it is not measured, and, with the surroundings' variation unmeasured, a
drift on the record's own knots (criterion `"nuisance"`, the default): for the surroundings-drift
model (`ambient_variation`) alone when it is one of the models separated, as the diagnosis
re-estimates it, and for every model when it is not (`drift_for_all`: the drift is then a
candidate the design does not model, which would take any slow gap it can follow, so such a gap
separates nothing). The gap is the distance between the two models' prediction sets over those
nuisances, linearised (weighted least squares); a transient from an unknown start separates
nothing. Criterion `"nuisance_drift"` lets every model re-estimate a drift
in every case: with the drift among the rivals, a slow body's input-driven warming then
separated nothing from the baseline either, and the design avoided exactly the slow power swings
that make a body significant (`experiments/results/design_experiment_study.md`, body case);
with the drift not among them, letting it follow nothing made the design's slow swings go to a
drift (radiation case). (The first criterion, `"span"`, projected
onto a constant per zone and the raw drift hats only: it counted the decay of an unknown initial
state as separation.) With three models (the top finding and two rivals, or with no rival the
runner-up and the baseline) the design maximises $\\sum_{a<b} \\log S_{ab}$, so that every pair
separates. $S$ is differentiable in $u$ through the coupled simulations
(`mechanisms.simulate_full`).

The input is held piecewise constant over `hold` samples (the minimum switching time) and kept
within the actuator limits by a smooth squash, $u = u_{min} + (u_{max} - u_{min})\\,
\\mathrm{sigmoid}(z)$; the objective is maximised over $z$ by Adam (`optax`) in one compiled
`lax.scan`, vmapped over two starts (a seeded PRBS at the limits, a small random input). The
best iterate is kept, then the best of it, its bang-bang rounding to the limits and the PRBS
itself, so the design never separates less than the PRBS it is compared with. The models start
at the estimation record's mean temperature, held at its mean input for a warm-up that the
objective leaves out.

Reference: the model-discrimination design of Box & Hill (1967), with the divergence of the
predictive distributions (Ljung 1999, §13) as the criterion.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from ..data import IOData, from_arrays
from ..errors import ConfigError
from ..inputs import prbs
from . import mechanisms as M
from .checks import as_records, concatenate
from .localise import event_matrix

#: samples held at the mean input before the designed record (left out of the objective)
WARMUP = 300
#: default minimum switching time, in samples
HOLD = 10
#: Adam iterations and step on the unconstrained input
N_STEPS = 150
LEARNING_RATE = 0.3
#: rivals of the top finding the design separates, besides it
MAX_RIVALS = 2
#: what a new record's nuisances absorb of a prediction gap (`design_experiment`'s `criterion`)
CRITERIA = ("nuisance", "nuisance_drift", "span")
#: weight of `over_limit` (per °C² and sample) against the objective, and the overshoot of
#: `y_max` tolerated in the final choice (°C)
OVER_PENALTY = 100.0
OVER_TOL = 0.5
#: the smallest validation MSE reduction of an unconfirmed candidate that asks for an experiment
OPEN_REDUCTION = 0.01
#: PRBS start, unconstrained: sigmoid(±START) ≈ 0.05 / 0.95 of the actuator range
START = 3.0


def unconfirmed(result: dict) -> list[dict]:
    """The candidates one test finds significant at the family-wise level and the other does not
    confirm, that reduce the validation MSE by at least `OPEN_REDUCTION`, best first (none
    flagged by the actuator's physics): what a diagnosis that names nothing leaves open."""
    flagged = {f["mechanism"] for f in result.get("flagged") or []}

    def passes(c, test):
        return bool(c.get(test, np.nan) >= c.get(test + "_critical", np.nan))

    rows = [c for c in result.get("candidates") or []
            if not c.get("significant") and c["mechanism"] not in flagged and "+" not in c["mechanism"]
            and c.get("val_reduction", 0.0) >= OPEN_REDUCTION
            and passes(c, "validation_z") != passes(c, "estimation_lr")]
    return sorted(rows, key=lambda c: -c["val_reduction"])


def rival_set(result: dict) -> tuple[tuple[str, ...], str]:
    """(models, why): the explanations the design must separate (two or three names).

    The top finding and its rivals (at most two); with no rival, the top finding against the
    runner-up (the other candidate that reduced the validation error most, its closest
    alternative explanation) and the baseline; with no finding, the two candidates that reduced
    the validation error most and the baseline (the new record must also show the better one
    significant), or the best one against the baseline when only one reduced it; a candidate
    the diagnosis leaves open (`unconfirmed`) is always among them, first."""
    fs = result.get("findings") or []
    if fs and fs[0].get("rivals"):
        return (fs[0]["mechanism"], *fs[0]["rivals"][:MAX_RIVALS]), "the top finding and its rivals"
    cands = sorted((c for c in result.get("candidates", []) if np.isfinite(c.get("val_reduction", np.nan))
                    and c["val_reduction"] > 0 and not (fs and c["mechanism"] == fs[0]["mechanism"])),
                   key=lambda c: -c["val_reduction"])
    if fs:
        if cands:
            return ((fs[0]["mechanism"], cands[0]["mechanism"], "baseline"),
                    "no rival: the top finding against the runner-up and the baseline")
        return (fs[0]["mechanism"], "baseline"), "no rival: the top finding against the baseline"
    if not cands:
        best = [c for c in result.get("candidates", []) if np.isfinite(c.get("val_reduction", np.nan))]
        if not best:
            raise ConfigError("design_experiment: the diagnosis has no candidate to separate from the baseline")
        return ((max(best, key=lambda c: c["val_reduction"])["mechanism"], "baseline"),
                "no finding: the best candidate against the baseline")
    open_ = unconfirmed(result)
    if open_:
        first = open_[0]["mechanism"]
        others = [c["mechanism"] for c in cands if c["mechanism"] != first]
        if others:
            return ((first, others[0], "baseline"),
                    "no finding: the candidate one test passes, the best other one and the baseline")
        return (first, "baseline"), "no finding: the candidate one test passes against the baseline"
    if len(cands) > 1:
        return ((cands[0]["mechanism"], cands[1]["mechanism"], "baseline"),
                "no finding: the two candidates that reduced the validation error most and the baseline")
    return (cands[0]["mechanism"], "baseline"), "no finding: the best candidate against the baseline"


def nuisance_basis(T: int, ts: float, drift: bool) -> np.ndarray:
    """Orthonormal columns `(T, k)` of what a new record's re-estimated nuisances absorb: a
    constant, and the drift hats of `mechanisms.drift_basis` when `drift`."""
    X = np.ones((T, 1))
    if drift:
        X = np.concatenate([X, M.drift_basis(T, ts, M.n_drift_knots(T, ts))], axis=1)
    q, r = np.linalg.qr(X)
    return q[:, np.abs(np.diag(r)) > 1e-9 * np.abs(r).max()]


def squash(z, lo, hi, hold: int, T: int):
    """Inputs `(T, nu)` from free variables `z (segments, nu)`: $lo + (hi - lo)\\,\\sigma(z)$,
    each held for `hold` samples."""
    return (lo + (hi - lo) * jax.nn.sigmoid(jnp.repeat(z, hold, axis=0)))[:T]


def drift_for_all(names, criterion: str = "nuisance") -> bool:
    """Whether every model of `names` re-estimates a surroundings drift on the new record (when
    the surroundings' variation is unmeasured): always under `"nuisance_drift"`; under
    `"nuisance"` only when the drift model (`ambient_variation`) is not one of `names` (it then
    re-estimates its own drift alone, as the diagnosis does)."""
    return bool(criterion == "nuisance_drift" or "ambient_variation" not in names)


def rival_context(models: dict, names, T: int, ts: float, u_rest, x_start, drift_all: bool = False):
    """Stacked parameters, switches, per-model simulation inputs and record states of the models
    `names` (mechanisms of the diagnosis' single-mechanism refits, or `baseline`); `drift_all`:
    every model, not only `ambient_variation`, re-estimates a drift on the new record (criterion
    `nuisance_drift`)."""
    lay = models["layout"]
    n = lay.n
    Tw = T + WARMUP
    kv = M.n_drift_knots(Tw, ts)
    P = float(models.get("period") or 0)
    ev = event_matrix(Tw, P, models["zone_phase"], offset=WARMUP) if P else np.zeros((Tw, n))
    thetas, ons, delays, recs = [], [], [], []
    for m in names:
        th = np.asarray(models["theta"][m], float)
        mech = () if m == "baseline" else (m,)
        thetas.append(th)
        ons.append(M.on_vector(mech))
        delays.append(float(models["delay"]) if m == "input_delay" else 0.0)
        _, gam = M.wall_parameters(th[:, lay.sl("log_tauw")][:, 0], th[:, lay.sl("log_gamma")][:, 0])
        tsl = models["level"] + models["ts_free"] * float(np.median(th[:, lay.sl("ts0")][:, 0]))
        w0 = tsl + (np.mean(x_start) - tsl) / (1.0 + gam)
        recs.append(np.concatenate([x_start, w0, np.zeros(kv), [0.0]]))
    shared = {"events": jnp.asarray(ev), "ts_level": jnp.asarray(float(models["level"])),
              "ts_free": jnp.asarray(float(models["ts_free"])), "wdev": jnp.zeros(Tw),
              "Phi": jnp.asarray(M.drift_basis(Tw, ts, kv)), "u_pad": jnp.asarray(u_rest),
              "ts": jnp.asarray(float(ts)), "t_ref": jnp.asarray(float(models["t_ref"]))}
    # what the diagnosis re-estimates on a new record (`select.diagnose`'s `validate`): every
    # zone's initial state, a body's initial state, the record's own surroundings level when
    # it is not measured, and, with the surroundings unmeasured, a drift on the record's own
    # knots for the drift model (`drift_all`: for every model, the former criterion)
    drift = not models["measured_ambient"]
    kr = M.n_drift_knots(T, ts)
    masks = np.zeros((len(names), 2 * n + kr + 1))
    masks[:, :n] = 1.0
    masks[:, n:2 * n] = np.array([float(m == "heat_accumulation") for m in names])[:, None]
    masks[:, 2 * n:2 * n + kr] = float(drift) * np.array([float(drift_all or m == "ambient_variation")
                                                          for m in names])[:, None]
    masks[:, -1] = float(models["ts_free"])
    ons_j = np.stack(ons)
    ia = M.MECHANISMS.index("ambient_variation")
    ons_j[:, ia] = np.maximum(ons_j[:, ia], masks[:, 2 * n])
    rec_r = [np.concatenate([r[:2 * n], np.zeros(kr), [0.0]]) for r in recs]
    nuis = {"on": jnp.asarray(ons_j), "rec": jnp.asarray(np.stack(rec_r)), "mask": jnp.asarray(masks),
            "f": {**shared, "events": jnp.asarray(ev[WARMUP:]), "wdev": jnp.zeros(T),
                  "Phi": jnp.asarray(M.drift_basis(T, ts, kr))}}
    return (jnp.asarray(np.stack(thetas)), jnp.asarray(np.stack(ons)), jnp.asarray(delays),
            jnp.asarray(np.stack(recs)), shared, lay, nuis)


def predictions(u, ctx):
    """The models' coupled simulations `(K, T, n)` on the input `u (T, nu)` (warm-up dropped)."""
    Th, on, delay, rec, shared, lay = ctx[:6]
    Tw = shared["Phi"].shape[0]
    full = jnp.concatenate([jnp.broadcast_to(shared["u_pad"], (Tw - u.shape[0], u.shape[1])), u])
    sim = lambda th, o, d, r: M.simulate_full(th, o, {**shared, "u": full, "delay": d}, lay, r)
    return jax.vmap(sim)(Th, on, delay, rec)[:, Tw - u.shape[0]:]


def nuisance_jacobians(u, ctx):
    """`(K, T n, R)`: each model's sensitivity to what a new record re-estimates (zero columns
    for what it does not), simulated from the record's start on the input `u (T, nu)`: what a
    refit of those nuisances can absorb of a prediction gap. Exact for the models that are
    linear in their states (all but radiation), a linearisation at the nominal start otherwise."""
    Th, on, delay, _rec, _shared, lay, nuis = ctx
    T, n = u.shape[0], lay.n

    def jac(th, o, d, r, m):
        sim = lambda rr: M.simulate_full(th, o, {**nuis["f"], "u": u, "delay": d}, lay, rr)
        return jax.jacfwd(sim)(r).reshape(T * n, -1) * m[None, :]

    return jax.vmap(jac)(Th, nuis["on"], delay, nuis["rec"], nuis["mask"])


def gap_residuals(u, ctx, Q, sigma):
    """`(P, T n)`: every pair's ($a < b$, `itertools.combinations` order) prediction gap on the
    input `u` outside what a new record's nuisances absorb, in noise units (zone fastest). With
    `Q (T, k)` given (the former criterion), that span is `Q`'s columns in every zone; with
    `Q = None` it is the span of both models' `nuisance_jacobians` (weighted least squares)."""
    y = predictions(u, ctx)
    K, T, n = y.shape
    a, b = np.triu_indices(K, 1)
    d = y[a] - y[b]
    if Q is not None:
        d = d - jnp.einsum("tk,pkn->ptn", Q, jnp.einsum("tk,ptn->pkn", Q, d))
        return (d / sigma).reshape(len(a), T * n)
    w = jnp.tile(1.0 / sigma, T)                                   # (T n,), zone fastest
    J = jax.lax.stop_gradient(nuisance_jacobians(u, ctx)) * w[None, :, None]
    X = jnp.concatenate([J[a], J[b]], axis=2)                      # (P, T n, 2R)
    X = X / jnp.maximum(jnp.linalg.norm(X, axis=1, keepdims=True), 1e-12)
    dw = d.reshape(len(a), T * n) * w[None, :]
    G = jnp.einsum("pti,ptj->pij", X, X) + 1e-9 * jnp.eye(X.shape[2])
    coef = jnp.linalg.solve(G, jnp.einsum("pti,pt->pi", X, dw)[..., None])[..., 0]
    return dw - jnp.einsum("pti,pi->pt", X, coef)


def separations(u, ctx, Q, sigma):
    """$S_{ab}(u)$ of every pair $a < b$ of the models (≥ 0), in `itertools.combinations` order:
    the squared norm of their `gap_residuals`."""
    return jnp.sum(gap_residuals(u, ctx, Q, sigma) ** 2, axis=1)


def pair_mask(names) -> np.ndarray:
    """1.0 for the pairs ($a < b$, `itertools.combinations` order) of `names` the design must
    separate: every pair, except that the baseline need only be told from the first model (the
    top finding, or the best candidate): a runner-up against the baseline settles nothing."""
    a, b = np.triu_indices(len(names), 1)
    return np.array([float(not ("baseline" in (names[i], names[j]) and i != 0)) for i, j in zip(a, b)])


def objective(u, ctx, Q, sigma, pm=None):
    """$\\sum_{a<b} \\log S_{ab}(u)$ over the pairs `pm` (default: all) keeps: every pair must
    separate (a product, like a D-criterion)."""
    ls = jnp.log(separations(u, ctx, Q, sigma) + 1e-300)
    return jnp.sum(ls if pm is None else pm * ls)


def evaluate(u, ctx, Q, sigma):
    """(`gap_residuals`, `predictions`) of the input `u` as NumPy arrays, from one compiled
    program (shared by every candidate of the same length, and cached on disk)."""
    g, y = _gaps_predictions(u, ctx, Q, sigma)
    return np.asarray(g), np.asarray(y)


@eqx.filter_jit
def _gaps_predictions(u, ctx, Q, sigma):
    return gap_residuals(u, ctx, Q, sigma), predictions(u, ctx)


def over_limit(u, ctx, y_max):
    """$\\sum$ over models, samples and zones of $\\max(0, \\hat y - y_{max})^2$ (°C²): how far the
    models' predicted temperatures on `u` go above `y_max (n,)`."""
    return jnp.sum(jax.nn.relu(predictions(u, ctx) - y_max) ** 2)


def _optimise(z0, lo, hi, hold, T, ctx, Q, sigma, n_steps, lr, pm, y_max):
    opt = optax.adam(lr)

    def loss(z):
        u = squash(z, lo, hi, hold, T)
        pen = 0.0 if y_max is None else OVER_PENALTY * over_limit(u, ctx, y_max)
        return -objective(u, ctx, Q, sigma, pm) + pen

    def step(carry, _):
        z, st, best_z, best_l = carry
        l, g = jax.value_and_grad(loss)(z)
        better = l < best_l
        best_z = jnp.where(better, z, best_z)
        best_l = jnp.where(better, l, best_l)
        upd, st = opt.update(g, st, z)
        return (optax.apply_updates(z, upd), st, best_z, best_l), l

    carry = (z0, opt.init(z0), z0, jnp.asarray(jnp.inf, z0.dtype))
    (z, _, best_z, best_l), hist = jax.lax.scan(step, carry, None, length=n_steps)
    lz = loss(z)
    return jnp.where(lz < best_l, z, best_z), jnp.minimum(lz, best_l), hist


@eqx.filter_jit
def _optimise_starts(Z0, lo, hi, hold, T, ctx, Q, sigma, n_steps, lr, pm, y_max):
    """`_optimise` from each start `Z0 (S, segments, nu)`; the best end point and histories."""
    z, l, hist = jax.vmap(lambda z0: _optimise(z0, lo, hi, hold, T, ctx, Q, sigma, n_steps, lr, pm, y_max))(Z0)
    return z[jnp.argmin(l)], hist


def design_experiment(result: dict, est: IOData, val: IOData, *, duration: int | None = None,
                      hold: int = HOLD, u_min=None, u_max=None, seed: int = 0,
                      n_steps: int = N_STEPS, learning_rate: float = LEARNING_RATE,
                      criterion: str = "nuisance", y_max=None) -> dict:
    """Design the input that best separates the diagnosis' rival explanations.

    **Arguments:**
    - `result`: the dict `diagnose(est, val)` returned (before `to_json`: it carries the fitted
      models under `_models`).
    - `est`, `val`: the records it was run on (`val` gives the noise level σ per zone); `est`
      may be the list of pooled estimation records.
    - `duration`: samples of the designed record (default: the (longest) estimation record's
      length).
    - `hold`: minimum switching time, samples. `u_min`, `u_max`: actuator limits per input
      (default: the range the two records' inputs span); inputs the diagnosis left out (idle)
      stay at their recorded value.
    - `seed`: the PRBS start and the PRBS it is compared with.
    - `criterion`: what a new record's re-estimated nuisances are taken to absorb of a gap
      (`CRITERIA`): `"nuisance"`, the span of both models' sensitivities to exactly what the
      diagnosis re-estimates (`nuisance_jacobians`); `"span"`, a constant and (surroundings
      unmeasured) the drift hats.
    - `y_max`: highest temperature (°C, per output or one for all) that any of the models may
      predict on the designed input (a penalty in the objective; of the final candidates a
      design within it is preferred, and with none within, the one that exceeds it least); an
      output the models predict higher when the rest input is held (where the designed record
      starts) gets that as its limit (`y_max_effective`); `None`: no limit.

    **Returns:** a dict with `rivals` (the K = 2 or 3 models separated, top first), `why`,
    `separation_designed` and `separation_prbs` (the weakest pair's $S$, on the design and on
    a PRBS over the same limits, switching time and length), `pair_separations` (the pairs
    `pair_mask` keeps), `duration`
    (samples), `duration_s`, `u` `(T, nu)`, `u_prbs`, `predictions` `(K, T, n)` on `u`,
    `gaps` and `gaps_prbs` (`gap_residuals` on `u` and on the PRBS, `(pairs, T n)`),
    `history` (−objective per iteration and start), `limits` and `record` (an `IOData` in the
    layout of `est`: the designed inputs, the top model's predicted outputs, measured signals at
    their means).
    """
    models = result.get("_models") if isinstance(result, dict) else None
    if models is None:
        raise ConfigError("design_experiment: `result` must be the dict `diagnose` returned, "
                          "before `to_json`")
    if not (isinstance(hold, (int, np.integer)) and hold >= 1):
        raise ConfigError(f"design_experiment: hold must be a positive integer of samples, got {hold!r}")
    records = as_records(est)
    est = concatenate(records)
    T = max(d.n_samples for d in records) if duration is None else duration
    if not (isinstance(T, (int, np.integer)) and T >= 2 * hold):
        raise ConfigError(f"design_experiment: duration must be an integer of at least two holds, got {T!r}")
    U = np.concatenate([np.asarray(est.u, float), np.asarray(val.u, float)])
    lo = np.broadcast_to(np.min(U, axis=0) if u_min is None else np.asarray(u_min, float), (est.n_inputs,))
    hi = np.broadcast_to(np.max(U, axis=0) if u_max is None else np.asarray(u_max, float), (est.n_inputs,))
    # inputs the diagnosis left out (idle in both records) stay at their recorded value
    idle = set(models.get("inputs_left_out") or ())
    keep = np.array([j for j, nm in enumerate(est.input_names) if nm not in idle], dtype=int)
    lo, hi = lo[keep], hi[keep]
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise ConfigError("design_experiment: the actuator limits need u_max > u_min for every input")
    names, why = rival_set(result)
    pm = pair_mask(names)
    jpm = jnp.asarray(pm)
    ts = float(est.ts)
    y_val = np.asarray(val.y, float)
    yhat = np.asarray(result["_arrays"]["yhat_augmented"])
    sigma = np.sqrt(np.maximum(np.mean((y_val - yhat) ** 2, axis=0), 1e-12))
    u_rest = np.clip(np.mean(np.asarray(est.u, float)[:, keep], axis=0), lo, hi)
    if criterion not in CRITERIA:
        raise ConfigError(f"design_experiment: criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    ctx = rival_context(models, names, T, ts, u_rest, np.mean(np.asarray(est.y, float), axis=0),
                        drift_all=drift_for_all(names, criterion))
    # "span" (the former criterion): a constant and, with the surroundings unmeasured (a drift
    # is always a candidate explanation of slow residuals), the drift hats, in every zone;
    # "nuisance": the span of the models' sensitivities to what the diagnosis re-estimates
    Q = (jnp.asarray(nuisance_basis(T, ts, not models["measured_ambient"])) if criterion == "span"
         else None)
    nseg = math.ceil(T / hold)
    bits = np.asarray(prbs(seed, nseg, len(keep), levels=(0.0, 1.0), hold=(1, 4)), float)
    small = np.asarray(jax.random.normal(jax.random.key(seed), bits.shape, jnp.float64))
    # two starts: the PRBS at the limits, and a small random input in the squash's linear range
    # (from which the gradient grows the most separating direction, as a power iteration does)
    Z0 = jnp.asarray(np.stack([START * (2.0 * bits - 1.0), 0.1 * small]))
    jlo, jhi, jsig = jnp.asarray(lo), jnp.asarray(hi), jnp.asarray(sigma)
    y_given = None
    if y_max is not None:
        y_max = np.broadcast_to(np.asarray(y_max, float), (est.n_outputs,))
        if not np.all(np.isfinite(y_max)):
            raise ConfigError("design_experiment: y_max must be finite")
        # the designed record starts from the models' state at the rest input (the warm-up): what
        # holding it reaches is allowed, else a model warmer there than any record (a short record
        # short of its steady state) would leave only the input that cools fastest (TCLab one heater)
        y_given = y_max
        rest = evaluate(jnp.asarray(np.broadcast_to(u_rest, (int(T), len(keep)))), ctx, Q, jsig)[1]
        y_max = np.maximum(y_max, np.max(rest, axis=(0, 1)))
    jymax = None if y_max is None else jnp.asarray(y_max)
    z, hist = _optimise_starts(Z0, jlo, jhi, int(hold), int(T), ctx, Q, jsig, int(n_steps),
                               float(learning_rate), jpm, jymax)
    u_prbs = lo + (hi - lo) * np.repeat(bits, hold, axis=0)[:T]
    # the squash never reaches the limits; its bang-bang rounding (often the optimum under
    # amplitude limits) and the PRBS start are candidates too: the best of the three is kept,
    # of those whose predictions stay within `y_max` (to `OVER_TOL`) if any does
    u_opt = np.asarray(squash(z, jlo, jhi, int(hold), int(T)))
    u_snap = np.where(u_opt >= 0.5 * (lo + hi), hi, lo)
    cands = (u_opt, u_snap, u_prbs)
    ev = [evaluate(jnp.asarray(c), ctx, Q, jsig) for c in cands]      # (gaps, predictions) each
    S = [np.sum(g ** 2, axis=1) for g, _ in ev]
    score = [float(np.sum(pm * np.log(s + 1e-300))) for s in S]     # `objective`
    top = [np.max(y, axis=(0, 1)) for _, y in ev]                     # (n,)
    within = [y_max is None or bool(np.all(t <= y_max + OVER_TOL)) for t in top]
    # with none within `y_max`, the one that exceeds it least (the penalised optimum, not the PRBS)
    rank = [(True, s) if w else (False, -float(np.max(t - y_max))) for s, t, w in zip(score, top, within)]
    best = max(range(len(cands)), key=lambda k: (*rank[k], -k))
    u = cands[best]
    s_design, s_prbs = S[best], S[2]
    pairs = [f"{names[a]}/{names[b]}" for a, b in zip(*np.triu_indices(len(names), 1))]
    yp = ev[best][1]
    w = np.broadcast_to(np.mean(np.asarray(est.w, float), axis=0), (T, est.w.shape[1]))
    u, u_prbs = (with_idle(v, np.asarray(est.u, float)[0], keep) for v in (u, u_prbs))
    record = from_arrays(u, yp[0], ts, w, input_names=est.input_names, output_names=est.output_names,
                         signal_names=est.signal_names,
                         notes=((f"designed experiment: inputs separate {', '.join(names)}; outputs are "
                                 f"`{names[0]}`'s prediction, to be replaced by the measurement"),))
    used = pm > 0
    return {"rivals": list(names), "why": why, "separation_designed": float(s_design[used].min()),
            "separation_prbs": float(s_prbs[used].min()),
            "pair_separations": {p: {"designed": float(a), "prbs": float(b)}
                                 for p, a, b, k in zip(pairs, s_design, s_prbs, used) if k},
            "duration": int(T), "duration_s": T * ts, "hold": int(hold), "criterion": criterion,
            "y_max": None if y_given is None else y_given.tolist(),
            "y_max_effective": None if y_max is None else y_max.tolist(), "within_y_max": within[best],
            "max_predicted": top[best].tolist(), "max_predicted_prbs": top[2].tolist(),
            "limits": {"inputs": [est.input_names[j] for j in keep], "u_min": lo.tolist(),
                       "u_max": hi.tolist()}, "sigma": sigma.tolist(),
            "u": u, "u_prbs": u_prbs, "predictions": yp,
            "gaps": ev[best][0][used], "gaps_prbs": ev[2][0][used],
            "history": np.asarray(hist),
            "record": record}


def with_idle(u_keep, u_idle, keep) -> np.ndarray:
    """All inputs `(T, nu)`: the designed columns `keep` from `u_keep`, the others held at
    their value in `u_idle (nu,)`."""
    out = np.tile(np.asarray(u_idle, float), (u_keep.shape[0], 1))
    out[:, keep] = u_keep
    return out


def to_json(design: dict, path=None) -> dict:
    """The JSON-ready summary of a design (no arrays); `path` the CSV it was written to."""
    keys = ("rivals", "why", "separation_designed", "separation_prbs", "pair_separations", "duration", "duration_s",
            "hold", "criterion", "y_max", "y_max_effective", "within_y_max", "max_predicted", "max_predicted_prbs", "limits",
            "sigma")
    out = {k: design[k] for k in keys}
    out["separation_ratio"] = (design["separation_designed"] / design["separation_prbs"]
                               if design["separation_prbs"] > 0 else float("inf"))
    out["path"] = None if path is None else str(path)
    return out


__all__ = ["CRITERIA", "design_experiment", "drift_for_all", "evaluate", "gap_residuals", "nuisance_basis",
           "nuisance_jacobians", "objective", "over_limit", "pair_mask", "predictions", "rival_context",
           "rival_set", "separations", "squash", "to_json", "with_idle"]
