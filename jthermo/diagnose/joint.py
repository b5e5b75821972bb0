"""Joint fits of a diagnosis: the augmented model refitted over all zones at once, grown by
forward selection.

A joint fit estimates every zone's parameters by the coupled simulation error
(`fitting.fit_joint`): zones interact through their simulated, not measured, temperatures and the
fitted exchange. `forward_select` fits the top mechanism jointly (surroundings at the record's
rest level unless both tests demand a fitted level), then adds, one round at a time, the pool's
mechanism that passes both tests of `decide.py` against the smaller joint model with the
strongest estimation evidence, up to `MAX_COMBINED` mechanisms. `grid_start` is the separable
least-squares start that the per-zone and the joint fits share.

Each round's additions start where the smaller model ended, and the smaller model is fitted on
beside them (`JointFits.extend`): the joint fits stop at `n_iter` iterations short of
convergence, so an addition judged against the smaller model as it was would count that
model's unfinished convergence as its own evidence. Started afresh instead, two in five
additions end above the smaller model's cost, and many more pass both tests on that unfinished
convergence alone, with the same top findings (measured by
`python experiments/diagnose_heldout_hard.py`).

A large joint model (more than `RESTRICT_ABOVE` free parameters: six zones and more on a
one-hour record) fits each addition *restricted*: the smaller model's zone parameters held but
for the losses, the added mechanism's free, a narrower Jacobian (`restricted_active`); the
smaller model is not refitted beside them (held, its unfinished convergence cannot count as an
addition's evidence), and the addition chosen is refitted in full and must pass both tests again.
Refitted in full, the additions at N = 9 mostly end above the smaller model's cost within
`JOINT_ITER` iterations, and fewer of the record's concealed effects are named, in about twice
the time (measured by `python experiments/diagnose_zone_scaling.py`).

Such a model is also *pruned* (`pruned_start`): every zone has a gain from every heater and, with
`lateral_conduction`, an exchange with every other zone, N² couplings; each zone fits only its
strongest ones (`kept_couplings`, chosen from the grid's gains and the per-zone
`lateral_conduction` fits' exchanges, before the joint stage), the others held (`JointFits.keep`:
one mask per zone, the same for a smaller model and its additions, and the tests' degrees of
freedom count what is free, `JointFits.n_added`). Pruning halves the joint stage's peak memory
at N = 16 and shortens it at N = 6, 9 and 16, and on the tour's kind of record names the lag and
the conduction at each N without a spurious `input_nonlinearity` (measured by
`python experiments/diagnose_zone_scaling.py`).

Every pool mechanism is tried, significant alone or not: most additions accepted
on the development records were not significant in the per-zone tests, and a pool of the
significant ones alone changes the augmented model of about a third of the records with a joint
stage (measured by `python experiments/diagnose_joint_pool_evidence.py`).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from . import decide as D
from . import mechanisms as M
from . import pool as PL
from .fitting import fit_joint

#: largest number of mechanisms in the augmented model
MAX_COMBINED = 3


def grid_start(y, u, ts, level, ts_free, n_grid: int = 40):
    """Per-zone baseline start by separable least squares: for each loss rate on a log grid the
    zone's simulated output is linear in its heater gains, initial temperature (and the
    surroundings level when it is free); keep the best rate. Returns (log_a, b, x0, ts0)."""
    from scipy.signal import lfilter

    T, n = y.shape
    nu = u.shape[1]
    rates = np.exp(np.linspace(np.log(1.0 / 3000.0), np.log(1.0 / 3.0), n_grid)) 
    k = np.arange(T)
    best = [(np.inf, None)] * n
    for a in rates:
        ad = math.exp(-a * ts)
        g = (1 - ad) / a
        # f[k] = sum_{m<k} ad^(k-1-m) g u[m]  (zero initial state)
        F = lfilter([0.0, g], [1.0, -ad], u, axis=0)
        X = [F, (ad ** k)[:, None]]
        one = 1.0 - ad ** k
        if ts_free:
            X.append(one[:, None])
        X = np.concatenate(X, axis=1)
        for i in range(n):
            target = y[:, i] - (0.0 if ts_free else level * one)
            coef, *_ = np.linalg.lstsq(X, target, rcond=None)
            c = float(np.mean((target - X @ coef) ** 2))
            if c < best[i][0]:
                best[i] = (c, (a, coef))
    log_a = np.empty(n)
    b = np.empty((n, nu))
    x0 = np.empty(n)
    ts0 = np.zeros(n)
    for i in range(n):
        a, coef = best[i][1]
        log_a[i] = math.log(a)
        bi = coef[:nu]
        b[i] = np.maximum(bi, M.GAIN_START_SHARE * max(np.max(bi), 1e-9))   # `mechanisms.live_gains`
        x0[i] = coef[nu]
        if ts_free:
            ts0[i] = coef[nu + 1] - level
    return log_a, b, x0, ts0


#: parameter groups of the joint fit's zone models (a zone's initial state, wall state and drift
#: are the record's, in `simulate_full`'s record vector; the level offset too)
JOINT_BASE = ("log_a", "log_b")
RECORD_GROUPS = ("x0", "xw0", "ts0", "drift", "x0_rec", "xw0_rec", "ts0_rec")


def joint_groups(mechs) -> tuple:
    return JOINT_BASE + tuple(g for m in mechs for g in M.MECH_PARAMS[m] if g not in RECORD_GROUPS)


@dataclasses.dataclass
class JointFits:
    """What the joint fits of one diagnosis share: records, layout, surroundings, starts.

    A joint fit estimates every zone's parameters at once by the coupled simulation error
    (`fitting.fit_joint`): zones interact through their simulated, not measured, temperatures.
    The surroundings are measured, or at the record's rest level (its first sample's mean zone
    temperature: the heaters were off before it) or that level plus a fitted offset (`free`)."""

    n: int
    lay: M.Layout
    y: np.ndarray
    yv: np.ndarray
    sh: dict
    ev: np.ndarray
    delay: float
    measured: bool
    measured_var: bool
    level: float
    neutral: np.ndarray
    u_pad_v: np.ndarray
    uv: np.ndarray
    n_iter: int
    slots: int
    val_slots: int
    n_active: int
    #: Jacobian width of an addition fitted with the smaller model's parameters held
    #: (`restricted_active`); 0: every addition is refitted in full
    n_active_add: int = 0
    #: `(n, P)` 1 where a zone parameter may be free (`pruned_start`); None: all of them
    keep: np.ndarray | None = None

    def zone_mask(self, groups) -> np.ndarray:
        """The zone parameters of `groups` that are free, every zone's, flat `(n P,)`."""
        m = np.tile(self.lay.mask(groups), self.n)
        return m if self.keep is None else m * self.keep.ravel()

    def n_added(self, mech) -> int:
        """Free parameters `mech` adds to a joint model, all zones (the tests' degrees of freedom)."""
        if self.keep is None or mech == "ambient_variation":   # the drift: the record's knots
            return M.n_added(mech, self.lay, shared_drift=True)
        return int(sum(self.keep[:, self.lay.sl(g)].sum() for g in M.MECH_PARAMS.get(mech, ())))

    def setup(self, free: bool, validation: bool = False) -> dict:
        """How a record enters a joint model: surroundings level `ts_level` (°C) and whether an
        offset is fitted (`ts_free`), the input before the record `u_pad`. Measured
        surroundings: as the per-zone fits. At rest (the default): the estimation record starts
        with the zones at the surroundings, so the level is its first sample's mean zone
        temperature, re-estimated on the validation record from that start (as every model's
        level is there), and the input before a record is its first value (off, for a record
        that starts at rest). Free: each
        record's first-sample level plus a fitted offset, the input before it its mean."""
        u_mean = self.u_pad_v if validation else np.asarray(self.sh["u_pad"])
        if self.measured:
            return {"ts_level": self.level, "ts_free": 0.0, "u_pad": u_mean}
        if free:
            return {"ts_level": float((self.yv if validation else self.y)[0].mean()), "ts_free": 1.0,
                    "u_pad": u_mean}
        return {"ts_level": float(self.y[0].mean()), "ts_free": float(validation),
                "u_pad": np.asarray((self.uv if validation else self.sh["u"])[0])}

    def start(self, theta, add=None) -> np.ndarray:
        """`theta` with the record groups cleared and the groups of mechanism `add` at their
        neutral values (`neutral`: the per-zone fits start the zones at another surroundings
        level, from where the coupled fit falls into worse minima)."""
        th = np.array(theta, float)
        th[:, self.lay.sl("ts0")] = 0.0
        for grp in M.MECH_PARAMS.get(add, ()):
            th[:, self.lay.sl(grp)] = self.neutral[:, self.lay.sl(grp)]
        return th

    def nested(self, cur: dict, add: str | None = None) -> tuple:
        """The model `cur` plus mechanism `add` (none: `cur` itself, fitted on), started where
        `cur` ended: its zone parameters (`start`), record parameters (initial states, drift,
        level offset) and level mode; the wall's initial states from the start's wall unless
        `cur` fitted them."""
        rec = np.array(cur["rec"], float)
        if "heat_accumulation" not in cur["set"]:
            for r in range(max(len(self.lay.records), 1)):
                rec[PL.record_entries(self.n, self.lay, r)[1]] = np.nan
        return self.start(cur["theta"], add), tuple(cur["set"]) + ((add,) if add else ()), cur["free"], rec

    def extend(self, cur: dict, pool, validate) -> tuple:
        """`cur` fitted on and each of `pool` added to it, all from where `cur` ended (one call):
        (`cur` refitted, additions). Every addition is judged against `cur` with as many
        iterations behind it: against `cur` as it was, an addition would count `cur`'s own
        unfinished convergence as its evidence.

        Large models (`n_active_add`): each addition is fitted with the smaller model's zone
        parameters held but for the losses (`fit(..., restricted=True)`), so `cur`'s own
        convergence cannot count as the addition's evidence and `cur` is not refitted."""
        if self.n_active_add:
            return cur, self.fit([self.nested(cur, m) for m in pool], validate, restricted=True)
        out = self.fit([self.nested(cur)] + [self.nested(cur, m) for m in pool], validate)
        return out[0], out[1:]

    def fit(self, models, validate, restricted: bool = False) -> list[dict]:
        """Fit `(θ start, mechanism set, free level[, record start])` models jointly on the
        estimation record (padded to `slots`: one compiled shape for every round), then validate
        them (padded to `val_slots`, the candidates' validation shape: no compile of its own).
        Record starts `(R,)` default to the first sample's temperatures, the wall's steady state
        between them and the level, no drift and no offset (NaN entries: that default)."""
        n, lay, T = self.n, self.lay, self.y.shape[0]
        nd = lay.n_drift
        S = self.slots
        models = list(models) + [models[-1]] * (S - len(models))
        R = PL.record_size(n, lay)
        size = n * lay.size
        rec0, mask = np.zeros((S, R)), np.zeros((S, size + R))
        setups = [self.setup(m[2]) for m in models]
        for j, (model, su) in enumerate(zip(models, setups)):
            th, st = model[0], model[1]
            _, gam = M.wall_parameters(th[:, lay.sl("log_tauw")][:, 0], th[:, lay.sl("log_gamma")][:, 0])
            rec0[j, :n] = self.y[0]
            rec0[j, n:2 * n] = su["ts_level"] + (rec0[j, :n].mean() - su["ts_level"]) / (1.0 + gam)
            rec0[j] = PL.record_start(rec0[j], self.y, lay, su["ts_level"], gam)
            if len(model) > 3:
                rec0[j] = np.where(np.isnan(model[3]), rec0[j], model[3])
            groups = ("log_a",) + joint_groups(st[-1:])[len(JOINT_BASE):] if restricted else joint_groups(st)
            mask[j, :size] = self.zone_mask(groups)
            mask[j, size:size + n] = 1.0
            mask[j, size + n:size + 2 * n] = float("heat_accumulation" in st)
            mask[j, size + 2 * n:size + 2 * n + nd] = float("ambient_variation" in st and not self.measured_var)
            mask[j, size + 2 * n + nd] = su["ts_free"]
            # later pooled records: their own states, and their own level unless it is measured
            PL.record_mask(mask[j], lay, size, "heat_accumulation" in st, not self.measured)
        fper = {"events": jnp.asarray(np.stack([self.ev] * S)),
                "delay": jnp.asarray([self.delay if "input_delay" in m[1] else 0.0 for m in models]),
                **{k: jnp.asarray(np.stack([su[k] for su in setups])) for k in setups[0]}}
        free = np.array([su["ts_free"] for su in setups])
        th, rec, yh, _ = fit_joint(jnp.asarray(np.stack([m[0] for m in models])),
                                   jnp.asarray(np.stack([M.on_vector(m[1]) for m in models])),
                                   jnp.asarray(rec0), jnp.asarray(mask), jnp.asarray(self.y),
                                   jnp.ones(T), fper, self.sh, lay, self.n_iter,
                                   self.n_active_add if restricted else self.n_active)
        th, rec, yh = np.array(th), np.asarray(rec), np.asarray(yh)
        # the record parameters, written where the per-zone models keep them (for the report)
        th[:, :, lay.sl("x0")] = rec[:, :n, None]
        th[:, :, lay.sl("ts0")] = rec[:, 2 * n + nd:2 * n + nd + 1, None] * free[:, None, None]
        th[:, :, lay.sl("drift")] = rec[:, None, 2 * n:2 * n + nd]
        th = PL.write_records(th, rec, lay)
        yhv = validate([(th[j], m[1], self.setup(m[2], True)) for j, m in enumerate(models)]
                       + [(th[-1], models[-1][1], self.setup(models[-1][2], True))] * (self.val_slots - S))
        return [{"theta": th[j], "rec": rec[j], "set": m[1], "free": bool(free[j]), "res": self.y - yh[j],
                 "e": self.yv - yhv[j], "yhat": yhv[j]} for j, m in enumerate(models)]


def joint_start(y, u, ts, level, lay) -> np.ndarray:
    """Joint fits' start `(n, P)`: each zone's loss and heater gains by the separable grid
    (`grid_start`) with the surroundings at `level`, every mechanism at its neutral value."""
    ga, gb, gx, _ = grid_start(y, u, ts, level, 0.0)
    return np.stack([M.initial_theta(lay, log_a=ga[i], log_b=np.log(gb[i]), x0=gx[i])
                     for i in range(y.shape[1])])


def _added_size(lay, mech, keep=None) -> int:
    """Free zone parameters a mechanism adds to a joint model (beyond `JOINT_BASE`), all zones
    (`keep`: `JointFits.keep`)."""
    keep = np.ones((lay.n, lay.size)) if keep is None else keep
    return int(sum(keep[:, lay.sl(g)].sum() for g in joint_groups((mech,))[len(JOINT_BASE):]))


def _width(n, lay, free) -> int:
    """Static Jacobian width: `free` zone parameters and the record parameters, to a multiple of 4."""
    return 4 * math.ceil((free + PL.record_size(n, lay)) / 4)


def joint_active(n, lay, first, pool, keep=None) -> int:
    """Static bound on the free parameters of a joint fit of `first` plus two of `pool`."""
    adds = sorted((_added_size(lay, m, keep) for m in pool), reverse=True)[:MAX_COMBINED - 1]
    gains = n * lay.nu if keep is None else int(keep[:, lay.sl("log_b")].sum())
    return _width(n, lay, n + gains + _added_size(lay, first, keep) + sum(adds))


#: joint models wider than this many Jacobian columns fit their additions restricted
#: (`JointFits.extend`): refitted in full, at N = 9 seven of eleven additions ended above the
#: smaller model's cost after `JOINT_ITER` iterations (measured by
#: `python experiments/diagnose_zone_scaling.py`); and they
#: keep only each zone's strongest couplings (`pruned_start`)
RESTRICT_ABOVE = 100


def restricted_active(n, lay, pool, keep=None) -> int:
    """Static bound on the free parameters of an addition fitted restricted: the zones' losses,
    the largest pool mechanism's groups and the record parameters."""
    return _width(n, lay, n + max((_added_size(lay, m, keep) for m in pool), default=0))


#: a coupling (a heater's gain, a neighbour's exchange) whose weight is below this share of its
#: zone's largest is held in a pruned joint model (`kept_couplings`) ...
KEEP_SHARE = 0.1
#: ... and so is any beyond the zone's this many strongest of each. On the tour's kind of record
#: (the printer's exchanges between zones that share a grid side, its heater footprint own 1,
#: side 0.36, diagonal 0.13) at N = 6, 9, 16 this keeps 26/36, 43/81, 79/256 gains (the held
#: ones carry 5, 11, 20 % of the gains' weight, held at the grid's estimate, not at zero) and
#: 16/30, 24/72, 52/240 exchanges: 14 of 14, 24 of 24, 44 of 48 grid sides, 2, 0, 8 others;
#: at most 3 held 39 % of the gain weight at N = 16, a share of 0.2 lost 8 grid sides more
#: (measured by `python experiments/diagnose_coupling_weights.py --zones 6,9,16`)
KEEP_MOST = 5


def kept_couplings(gain, u, exch, y, share: float = KEEP_SHARE, most: int | None = KEEP_MOST) -> tuple:
    """Which heater gains and exchanges of each zone a pruned joint model fits: `gain (n, nu)`
    heater gains (°C/s per input unit), `u (T, nu)` the inputs, `exch (n, n-1)` exchange rates
    (1/s; row i: the other zones in order) or None, `y (T, n)` the zone temperatures. A gain
    weighs `gain[i, h] · rms(u_h)` (the heat rate it carries), an exchange between zones i and j
    the mean of `exch[i, j] · rms(y_j - y_i)` and `exch[j, i] · rms(y_i - y_j)` (the heat rate the
    temperature difference drives; a conduction is one for both zones, and a zone's own fit may
    leave its exchanges where they started); each zone keeps those of at least `share` of its
    largest, at most its `most` strongest of each. Returns boolean `(n, nu)`, `(n, n-1)` (all
    True where `exch` is None)."""
    rms = lambda v: np.sqrt(np.mean(np.square(v), axis=0))

    def keep(w):
        rank = np.argsort(np.argsort(-w, axis=1, kind="stable"), axis=1)
        return (w >= share * w.max(axis=1, keepdims=True)) & (rank < (most or w.shape[1]))

    n = y.shape[1]
    keep_b = keep(np.asarray(gain) * rms(u)[None, :])
    if exch is None or n < 2:
        return keep_b, np.ones((n, max(n - 1, 0)), bool)
    others = np.array([[j for j in range(n) if j != i] for i in range(n)])
    rows = np.repeat(np.arange(n), n - 1)
    w = np.zeros((n, n))
    w[rows, others.ravel()] = (np.asarray(exch)[:, :n - 1] * rms(y[:, others] - y[:, :, None])).ravel()
    w = (w + w.T) / 2.0
    return keep_b, keep(w[rows, others.ravel()].reshape(n, n - 1))


def pruned_start(neutral, lay, u, y, theta_k) -> tuple:
    """A wide joint model's couplings limited to those that matter (`kept_couplings`): the heater
    gains of the joint start `neutral (n, P)` (the separable grid's, `joint_start`) and the
    exchanges of the per-zone `lateral_conduction` fits `theta_k (n, P)` (None: no exchange is
    pruned). The others are held: a gain at the grid's (small: at least 0.02 of the zone's
    largest), an exchange at its per-zone fit's. Returns (`JointFits.keep`, the start with the
    held exchanges written)."""
    n = lay.n
    keep_b, keep_k = kept_couplings(np.exp(neutral[:, lay.sl("log_b")]), u,
                                    None if theta_k is None else np.exp(theta_k[:, lay.sl("log_k")]), y)
    keep = np.ones((n, lay.size))
    keep[:, lay.sl("log_b")] = keep_b
    kk = keep[:, lay.sl("log_k")]          # a view: written through into `keep`
    kk[:, :n - 1] = keep_k
    start = np.array(neutral, float)
    if theta_k is not None:
        k0 = start[:, lay.sl("log_k")]
        start[:, lay.sl("log_k")] = np.where(kk > 0, k0, theta_k[:, lay.sl("log_k")])
    return keep, start


def judge(cur, cand, n_tests, dof, k_extra) -> dict:
    """Both tests of `cand` against the smaller model `cur` (joint fits' residuals)."""
    zc, lc = D.thresholds(n_tests, dof)
    zv = D.predictive_z(cur["e"], cand["e"], k_extra)
    lr = D.likelihood_ratio(cur["res"], cand["res"])
    ok = bool(zv >= zc and lr >= lc and np.mean(cand["e"] ** 2) < np.mean(cur["e"] ** 2))
    return {"validation_z": zv, "validation_z_critical": zc, "estimation_lr": lr,
            "estimation_lr_critical": lc, "passed": ok}


def rival_additions(best, others, k_val) -> dict:
    """The additions of a round that also passed both tests and that the chosen one `best`
    does not beat on the validation record at `decide.RIVAL_LEVEL` (Diebold–Mariano, charged for
    the parameters each re-estimates there), and the $z$ over the closest of them: of several
    additions that explain the same residual (a lamp exponent, radiation, a slow body) the
    strongest likelihood ratio is named, but not as a confident finding."""
    z = {m: D.predictive_z(a["e"], best["e"], k_val(best["set"]) - k_val(a["set"])) for m, a in others}
    return rivals_among(z, ())


def unfitted_additions(judged) -> dict:
    """The additions of a round, `judged` [(mechanism, `judge` result)], whose joint fit ended
    above the smaller model's cost beyond chance: estimation likelihood ratio below minus its
    critical value. A nested model fitted to its optimum is never worse than the model it
    contains, so such a fit stopped short (the coupled fits stop at `n_iter`) and its mechanism
    was not tested: the chosen addition does not beat it, and it stays a tie ($z = 0$:
    `{mechanism: 0.0}`, as `rival_additions` reads a rival). On the loop's development set, a
    two-lag heater's single lag was grown by a lamp exponent at confidence 0.999 while the dead
    time, which a second lag resembles, ended 260 above the lag's cost."""
    return {m: 0.0 for m, t in judged if t["estimation_lr"] < -t["estimation_lr_critical"]}


def rivals_among(z_over: dict, chosen) -> dict:
    """Rivals and the $z$ over the closest of the additions `z_over` ({mechanism: z of the
    chosen one over it}) that did not join the augmented model later (`chosen`): one that
    joined is not an alternative to it."""
    z = {m: v for m, v in z_over.items() if m not in chosen}
    return {"rivals": [m for m, v in z.items() if D.is_rival(v)],
            "z_over_runner": min(z.values()) if z else None, "z_over": z_over}


def forward_select(js, validate, k_val, top, pool, fit_of):
    """Forward selection in the joint structure: fit the top mechanism jointly (surroundings at
    the rest level; a fitted level only if both tests demand it), then add, one round at a time,
    of the pool's mechanisms that pass both tests given the chosen ones the one with the smallest
    χ² tail probability of its likelihood ratio, up to `MAX_COMBINED`. Returns (augmented model, tried combinations, chosen)."""
    th0 = js.start(js.neutral, top)
    chosen = (top,)
    out = js.fit([(th0, chosen, False)] + ([] if js.measured else [(th0, chosen, True)]), validate)
    cur, free, level_test = out[0], False, None
    if not js.measured:
        level_test = judge(out[0], out[1], 1, 1, 0.0)
        if level_test["passed"]:
            cur, free = out[1], True
    # every addition starts where the smaller model ended (`JointFits.extend`): started afresh,
    # two in five of them ended above the smaller model's cost
    cur, adds = js.extend(cur, pool, validate) if pool else (cur, [])
    tried = []
    pool = list(pool)
    while adds:
        best, passing, judged = None, [], []
        for m, a in zip(pool, adds):
            t = judge(cur, a, len(pool), js.n_added(m), k_val(a["set"]) - k_val(chosen))
            judged.append((m, t))
            tried.append({"mechanisms": list(a["set"]), **t, "accepted": False,
                          "mean_fit_percent": float(np.mean(fit_of(a["e"])))})
            # among those that pass both tests, the strongest evidence on the estimation record
            # (χ² tail of the likelihood ratio): the validation MSE would favour a mechanism whose
            # parameters are re-estimated on the validation record itself (a drift)
            ev = D.chi2_log_tail(t["estimation_lr"], js.n_added(m))
            # an addition that predicts the validation record worse is never the augmented model
            if t["passed"] and D.not_worse(js.yv, a["e"], cur["e"]):
                passing.append((m, a))
                if best is None or ev < best[3]:
                    best = (tried[-1], a, m, ev)
        if best is None:
            break
        # ties judged among the round's fits as they were (a restricted one against restricted
        # ones: its full refit below would beat them by the parameters it alone moved)
        ties = rival_additions(best[1], [(m, a) for m, a in passing if m != best[2]], k_val)
        # and an addition whose fit stopped short of the smaller model's cost was not tested
        ties["z_over"] = {**unfitted_additions(judged), **ties["z_over"]}
        best[0].update(rivals_among(ties["z_over"], ()))
        if js.n_active_add:
            # the restricted addition chosen, refitted in full from where it ended, and judged
            # again: accepted only if the full model passes both tests too
            full = js.fit([js.nested(best[1])], validate)[0]
            t = judge(cur, full, len(pool), js.n_added(best[2]),
                      k_val(full["set"]) - k_val(chosen))
            best[0].update({**t, "refitted_in_full": True,
                            "mean_fit_percent": float(np.mean(fit_of(full["e"])))})
            if not (t["passed"] and D.not_worse(js.yv, full["e"], cur["e"])):
                best[0]["passed"] = False
                break
            best = (best[0], full, best[2], best[3])
        best[0]["accepted"] = True
        best[0]["effect_rms_C"] = D.rms(cur["yhat"] - best[1]["yhat"])
        cur, chosen = best[1], best[1]["set"]
        pool.remove(best[2])
        if len(chosen) >= MAX_COMBINED or not pool:
            break
        cur, adds = js.extend(cur, pool, validate)
    cur = {**cur, "level_mode": "measured" if js.measured else ("fitted" if free else "rest"),
           "level_test": level_test}
    return cur, tried, list(chosen)

