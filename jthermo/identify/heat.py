"""Fitting under what heat does (`fit(..., physics="heat")`, the default).

When the inputs are heat commands and the outputs temperatures, every family returns a model
that is stable, whose heaters lower no sensor's steady temperature, whose step responses move
against their final direction by no more than the noise, and whose steady states over the
recorded inputs cover the recorded temperatures (`models.plausibility.heat_check`):

- `ss`: the family's own (innovations-form) state space where it passes the check and
  simulates its record to `OWN_FIT_KEEP` %, so a well-excited record's fit is what it would be
  without the constraint; else the better plausible one of it and the positive
  (compartmental) state space (`models.positive`, fitted by `positive.fit_positive`):
  plausible by construction. Its automatic orders compare one node per sensor (n = ny) with
  one more hidden node per sensor (n = 2 ny: the heater's body, or the sensor's slow
  surroundings, `positive.SLOW_SHARES`) by the criterion of their
  simulation errors.
- `arx`, `armax`, `oe`, `bj`: the screened candidates are fitted as before and checked; the
  best plausible one by the criterion is kept. Where none is, the family's first-order model at
  the estimated delay, then the better fit of two plausible-by-construction models (stable,
  non-negative impulse responses): the constrained first order (`constrained_polynomial`: a
  positive, uncoupled one-node-per-sensor fit from rest) and, up to `ALTERNATIVE_MAX_OUTPUTS`
  sensors, the positive state space of `fit_ss_heat` (coupled nodes, free initial state)
  written as the family's polynomials (`positive_polynomial`). Every step is reported in
  `extra["physics"]["path"]`.
- `greybox`: positive by construction (first-order zones, log-parametrised gains); a measured
  signal is its surroundings only when its name says so (`SURROUNDINGS_WORDS`).

Before any family: a logged set point (a `w_` column whose name holds `target`, `setpoint` or
`set_point`, `models.plausibility.SETPOINT_WORDS`) is left out (neither an input nor a
disturbance), so is an input constant over the record (a heater kept off); the remaining measured
signals (a fan) are disturbances of the plant.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np

from ..data import IOData, idle_inputs, keep_inputs
from ..errors import ConfigError, DataError, FitError, JThermoError, ModelError
from ..models.plausibility import heat_check, is_setpoint_signal, starts_at_rest
from ..models import statespace_numpy
from ..models.polynomial import Polynomial
from .orders import information_criterion
from .positive import fit_positive
from .result import FitResult

PHYSICS = ("heat", "none")
#: a measured signal whose name holds one of these is the greybox model's surroundings (°C)
SURROUNDINGS_WORDS = ("amb", "surr", "room", "env")
#: options of `fit` that the positive state space (the heat path's fallback for ss) takes
SS_OPTIONS = ("max_steps",)
#: the family's own plausible state space is kept without trying the positive one when it
#: simulates its record at least this well (mean fit %): a well-excited record's fit stays as
#: it was, a closed-loop hold (a printer bed) gets the better of the two
OWN_FIT_KEEP = 90.0
#: ... and when the record has more sensors than this: the positive fit's dense Jacobian has
#: ~n² columns for n ≥ 2 ny states, so at a printer's 16 zones the alternative alone costs
#: ~900 CPU s against seconds for the plausible model already in hand
ALTERNATIVE_MAX_OUTPUTS = 4


def heat_data(data: IOData) -> tuple[IOData, dict]:
    """`data` without logged set points and constant inputs (while another input varies), and
    what was left out: `{"dropped_signals", "dropped_inputs", "rest_samples"}`. A record whose
    inputs are all constant is a step from rest when it starts at rest (`rest_before`); it is
    returned with that rest put before it (`rest_samples` > 0), else refused."""
    keep = [j for j, n in enumerate(data.signal_names) if not is_setpoint_signal(n)]
    dropped_w = [n for n in data.signal_names if is_setpoint_signal(n)]
    if dropped_w:
        data = data.replace(w=np.asarray(data.w)[:, keep],
                            signal_names=tuple(data.signal_names[j] for j in keep))
    idle = idle_inputs(data)
    dropped_u, rest = [], 0
    if idle and len(idle) == data.n_inputs and data.n_inputs:
        data, dropped_u, rest = rest_before(data)
        idle = []
    if idle and len(idle) < data.n_inputs:
        dropped_u = [data.input_names[j] for j in idle]
        data = keep_inputs(data, [n for j, n in enumerate(data.input_names) if j not in idle])
    return data, {"dropped_signals": dropped_w, "dropped_inputs": dropped_u,
                  "rest_samples": rest}


#: a step from rest gets at least this many samples of rest before it ...
REST_SAMPLES = 30
#: ... or this share of the record's length, whichever is more
REST_SHARE = 0.05


def _noise_std(y: np.ndarray) -> np.ndarray:
    """Each column's noise level from its first differences (median absolute deviation)."""
    d = np.diff(y, axis=0)
    return 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0) / np.sqrt(2.0)


def rest_before(data: IOData) -> tuple[IOData, list, int]:
    """A record whose inputs are all constant: the step from rest it is, or a `DataError`.

    Heaters held at constant powers $u_j \ne 0$ from the first sample on, with every output
    at its lowest reading there (`models.plausibility.starts_at_rest`),
    is the step test of a device switched on at rest, as TCLab step tests are logged: the
    heaters were off before $t_0$ and the outputs at their first reading. That initial
    condition is what carries the information (the response to $0 \to u$); it is written
    into the record as `max(REST_SAMPLES, REST_SHARE T)` samples of rest before $t_0$
    ($u = 0$, $y = y(0)$, $w = w(0)$), so every family's fitter, screening and initial-state
    handling see the step itself. Inputs constant at 0 are left out.

    **Returns:** `(data, dropped input names, samples put before)`.
    """
    u = np.asarray(data.u, np.float64)
    y = np.asarray(data.y, np.float64)
    on = [j for j in range(data.n_inputs) if abs(u[0, j]) > 0]
    if not on:
        raise DataError("IOData: every input is constant at 0 (no heater was on): the record "
                        "carries no information on what the heaters do")
    if not starts_at_rest(y, _noise_std(y)):
        j = int(np.argmax(y[0] - y.min(axis=0) - 0.05 * np.ptp(y, axis=0)))
        raise DataError(f"IOData: every input is constant, and the record does not start at rest "
                        f"(y_{data.output_names[j]} starts at {y[0, j]:.4g}, above its lowest "
                        f"{y[:, j].min():.4g}): it carries no information on what the heaters do")
    dropped = [data.input_names[j] for j in range(data.n_inputs) if j not in on]
    if dropped:
        data = keep_inputs(data, [data.input_names[j] for j in on])
    k = max(REST_SAMPLES, int(np.ceil(REST_SHARE * data.n_samples)))
    w = np.asarray(data.w, np.float64)
    note = (f"a step from rest: {k} samples of rest (inputs 0, outputs and signals at their "
            "first reading) put before the record")
    return data.replace(
        u=np.concatenate([np.zeros((k, data.n_inputs)), np.asarray(data.u)]),
        y=np.concatenate([np.repeat(y[:1], k, axis=0), y]),
        w=np.concatenate([np.repeat(w[:1], k, axis=0), w]),
        t0=float(data.t0) - k * float(data.ts), notes=(*data.notes, note)), dropped, k


def _orders_text(o: dict) -> str:
    return ",".join(f"{k}={v}" for k, v in o.items())


def _criterion(res: FitResult, data: IOData, p: int, criterion: str) -> float:
    eps = np.asarray(data.y) - np.asarray(res.model.simulate(data.u, data.w[:, :res.model.n_signals]
                                                             if res.model.n_signals else None))
    v = information_criterion(eps, p, criterion)
    return float(v) if np.isfinite(v) else np.inf


def _sim_error(r: FitResult, data: IOData) -> np.ndarray:
    """Simulation errors of a positive fit from its estimated initial state."""
    ss = r.model
    A, C = np.asarray(ss.A), np.asarray(ss.C)
    x = np.asarray(r.x0, np.float64)
    w = np.asarray(data.w[:, :ss.Bw.shape[1]], np.float64) - np.asarray(ss.w0)
    drive = np.asarray(data.u) @ np.asarray(ss.B).T + w @ np.asarray(ss.Bw).T
    out = np.empty((data.n_samples, C.shape[0]))
    for k in range(data.n_samples):
        out[k] = C @ x
        x = A @ x + drive[k]
    return np.asarray(data.y) - np.asarray(ss.y0) - out


def fit_ss_heat(data: IOData, orders: dict | None, criterion: str, fitter=None, *,
                seed: int = 0, n_starts: int = 8, progress=None,
                **kw) -> tuple[FitResult, list]:
    """The family's own state space (`fitter`, the innovations form of `fit_statespace`, with
    every option) where it passes `heat_check` and simulates its record to `OWN_FIT_KEEP` (or
    has more than `ALTERNATIVE_MAX_OUTPUTS` sensors) —
    a virtual printer's or any well-excited record's fit is left as it was — else the positive
    state space of order `orders["n"]` or, automatically, n = ny or 2 ny (options:
    `SS_OPTIONS`), or the plausible own fit where that simulates its record better."""
    path, own = [], None
    if fitter is not None:
        try:
            r = fitter.run(data, "ss", orders, seed=seed, n_starts=n_starts, progress=progress,
                           **kw)
        except ConfigError:
            raise
        except JThermoError as exc:
            path.append(f"ss {_orders_text(orders or {}) or 'automatic'}: refused ({exc})")
        else:
            chk = heat_check(r.model, data)
            if chk["plausible"]:
                own_fit = _mean_fit(r.model, data)
                path.append(f"ss {_orders_text(r.orders)}: plausible, fit {own_fit:.1f} %")
                if (own_fit >= OWN_FIT_KEEP or data.n_outputs > ALTERNATIVE_MAX_OUTPUTS
                        or orders is not None and orders["n"] < data.n_outputs):
                    return r, path
                own = (own_fit, r)
            else:
                path.append(f"ss {_orders_text(r.orders)}: implausible ({chk['warnings'][0]})")
    kw = {k: v for k, v in kw.items() if k in SS_OPTIONS}
    ny = data.n_outputs
    if orders is not None and orders["n"] < ny:
        raise ModelError(f"fit: a positive state space needs n >= {ny} (one node per sensor), "
                         f"got n = {orders['n']}")
    cands = [orders["n"]] if orders is not None else [ny, 2 * ny]
    best = None
    for n in cands:
        try:
            r = fit_positive(data, n, **kw)
        except FitError as exc:
            path.append(f"ss n={n}: {exc}")
            continue
        chk = heat_check(r.model, data)
        p = len(r.extra["positive"]["theta"]) + n + ny
        v = float(information_criterion(_sim_error(r, data), p, criterion))
        path.append(f"ss n={n} positive: {criterion} {v:.4g}"
                    + ("" if chk["plausible"] else f", {chk['warnings'][0]}"))
        key = (not chk["plausible"], v)
        if best is None or key < best[0]:
            best = (key, r)
    if best is None:
        if own is not None:
            return own[1], path
        raise FitError(f"fit: no positive state space could be fitted ({path[-1]})")
    if own is not None and not best[0][0]:
        pos_fit = _mean_fit(best[1].model, data)
        if own[0] >= pos_fit:
            path.append(f"ss {_orders_text(own[1].orders)} kept: fit {own[0]:.1f} % against the "
                        f"positive state space's {pos_fit:.1f} %")
            return own[1], path
        path.append(f"ss n={best[1].orders['n']} positive chosen: fit {pos_fit:.1f} % against "
                    f"{own[0]:.1f} %")
    elif own is not None:
        return own[1], path
    return best[1], path


def _mean_fit(model, data: IOData) -> float:
    """Mean simulation fit % of a state-space model on `data` from the least-squares initial
    state (what `validate.compare` and `jthermo fit` report)."""
    w = np.asarray(data.w)[:, :model.n_signals] if model.n_signals else None
    _, yhat = statespace_numpy.initial_state(model, data.y, data.u, w)
    y = np.asarray(data.y, np.float64)
    num = np.linalg.norm(y - yhat, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    return float(np.mean(100.0 * (1.0 - num / np.where(den > 0, den, 1.0))))


def first_order(family: str, nk: int) -> dict:
    """The family's first-order orders at delay `nk` (MATLAB's naming)."""
    return {"arx": {"na": 1, "nb": 1, "nk": nk}, "armax": {"na": 1, "nb": 1, "nc": 1, "nk": nk},
            "oe": {"nb": 1, "nf": 1, "nk": nk},
            "bj": {"nb": 1, "nc": 1, "nd": 1, "nf": 1, "nk": nk}}[family]


def constrained_polynomial(data: IOData, family: str) -> FitResult:
    """A plausible model of `family` by construction: the positive state space with one node
    per sensor and no coupling between nodes, from rest (x0 = 0), fitted by simulation error,
    is per output $y_i = y_{0,i} + \\sum_j \\frac{b_{ij} q^{-1}}{1 - a_i q^{-1}} u_j$ with
    $0 < a_i < 1$ and $b_{ij} \\ge 0$: ARX/ARMAX take $A_i = 1 - a_i q^{-1}$, OE/BJ
    $F_{ij} = 1 - a_i q^{-1}$ (noise polynomials C = D = 1)."""
    r = fit_positive(data, data.n_outputs, free_x0=False, coupled=False)
    ss = r.model
    a = np.diag(np.asarray(ss.A))
    b = (np.asarray(ss.C).diagonal()[:, None] * np.asarray(ss.B))[:, :, None]
    ny, nu = b.shape[:2]
    kw = dict(b=b, nk=1, ts=data.ts, u0=np.zeros(nu), y0=np.asarray(ss.y0))
    if family in ("arx", "armax"):
        model = Polynomial(a=-a[:, None], **kw)
        orders = {"na": 1, "nb": 1, "nk": 1} if family == "arx" else \
            {"na": 1, "nb": 1, "nc": 0, "nk": 1}
    else:
        model = Polynomial(f=np.repeat(-a[:, None, None], nu, axis=1), **kw)
        orders = {"nb": 1, "nf": 1, "nk": 1} if family == "oe" else \
            {"nb": 1, "nc": 0, "nd": 0, "nf": 1, "nk": 1}
    return FitResult(model=model, family=family, orders=orders, converged=r.converged,
                     cost=r.cost, extra={"constrained": True})


#: a state space written as polynomials is kept only when their impulse responses agree to
#: this share of the largest one (a high-order characteristic polynomial loses digits)
CONVERSION_TOL = 1e-6


def positive_polynomial(ss, family: str, horizon: int = 400) -> Polynomial | None:
    """The discrete state space `ss` (D = 0, u0 = 0: a positive fit) written as `family`'s
    polynomials, or None where that loses digits (`CONVERSION_TOL`).

    Each output gets the common denominator $a(q^{-1}) = \\det(I - A q^{-1})$
    (`np.poly` of A: its roots are A's eigenvalues, so stability carries over); with the
    Markov parameters $h_k = C A^{k-1} B$ the numerators are
    $n_k = \\sum_{m=0}^{k-1} a_m h_{k-m}$, $k = 1..n$ ($a_0 = 1$), since $a \\cdot H = N$ has
    degree n in $q^{-1}$. ARX/ARMAX take $A_i = a$, OE/BJ $F_{ij} = a$ (C = D = 1), nk = 1: the
    impulse responses are the state space's, non-negative when it is positive."""
    A, B, C = (np.asarray(m, np.float64) for m in (ss.A, ss.B, ss.C))
    n, ny, nu = A.shape[0], C.shape[0], B.shape[1]
    a = np.real(np.poly(A))
    h = np.empty((max(horizon, n) + 1, ny, nu))
    h[0] = 0.0
    x = B.copy()
    for k in range(1, h.shape[0]):
        h[k] = C @ x
        x = A @ x
    num = np.stack([sum(a[m] * h[k - m] for m in range(k)) for k in range(1, n + 1)], axis=-1)
    kw = dict(b=num, nk=1, ts=ss.ts, u0=np.zeros(nu), y0=np.asarray(ss.y0))
    if family in ("arx", "armax"):
        model = Polynomial(a=np.repeat(a[None, 1:], ny, axis=0), **kw)
    else:
        model = Polynomial(f=np.broadcast_to(a[1:], (ny, nu, n)).copy(), **kw)
    got = np.asarray(model.impulse_response(horizon))
    want = h[:horizon] if got.shape[0] == horizon else h[:got.shape[0]]
    scale = max(float(np.abs(h).max()), 1e-300)
    if not np.all(np.isfinite(got)) or np.abs(got - want).max() > CONVERSION_TOL * scale:
        return None
    return model


def _positive_orders(family: str, n: int) -> dict:
    return {"arx": {"na": n, "nb": n, "nk": 1}, "armax": {"na": n, "nb": n, "nc": 0, "nk": 1},
            "oe": {"nb": n, "nf": n, "nk": 1},
            "bj": {"nb": n, "nc": 0, "nd": 0, "nf": n, "nk": 1}}[family]


#: the last record's positive state space: the same for every polynomial family fitted to it
_POSITIVE_MEMO: dict = {}


def _record_key(data: IOData, criterion: str) -> tuple:
    h = hashlib.sha1(repr((data.u.shape, data.y.shape)).encode())
    for arr in (data.u, data.y):
        h.update(np.ascontiguousarray(np.asarray(arr, np.float64)).tobytes())
    return h.hexdigest(), float(data.ts), criterion


def positive_as_polynomial(data: IOData, family: str, criterion: str) -> tuple[FitResult | None,
                                                                                 list]:
    """The heat path's positive state space (`fit_ss_heat` without the family's own fit:
    coupled nodes, free initial state; measured signals left out, as polynomials carry none)
    written as `family`'s polynomials: `(result or None, path)`; None where no positive fit
    could be made or written as polynomials, or the record has more than
    `ALTERNATIVE_MAX_OUTPUTS` sensors."""
    if data.n_outputs > ALTERNATIVE_MAX_OUTPUTS:
        return None, [f"{family} from the positive state space: not tried beyond "
                      f"{ALTERNATIVE_MAX_OUTPUTS} sensors (its fit's cost grows as n^2 columns)"]
    if data.w.shape[1]:         # polynomials carry no measured signals: fitted without them
        data = data.replace(w=np.zeros((data.n_samples, 0)), signal_names=())
    key = _record_key(data, criterion)
    hit = _POSITIVE_MEMO.get(key)       # read once: another thread may replace the entry
    if hit is None:
        try:
            hit = fit_ss_heat(data, None, criterion)
        except FitError as exc:
            return None, [f"{family} from the positive state space: {exc}"]
        _POSITIVE_MEMO.clear()
        _POSITIVE_MEMO[key] = hit
    r, path = hit
    n = r.model.A.shape[0]
    model = positive_polynomial(r.model, family)
    if model is None:
        return None, [*path, f"{family} from the positive state space n={n}: not written as "
                      "polynomials (its characteristic polynomial loses digits)"]
    res = FitResult(model=model, family=family, orders=_positive_orders(family, n),
                    converged=r.converged, cost=r.cost,
                    extra={"constrained": True, "positive_state_space": True})
    return res, path


def fit_polynomial_heat(data: IOData, family: str, fitter, screen, criterion: str,
                        **kw) -> tuple[FitResult, list, list | None]:
    """Plausible candidates only (module docstring): `(result, path, order table)`;
    `screen(data, family)` returns the screened `(candidates, table)`."""
    from .polynomial import n_params_per_output

    path, table = [], None
    try:
        candidates, table = screen(data, family)
    except JThermoError as exc:
        candidates = []
        path.append(f"screening: {exc}")
    nk = candidates[0]["nk"] if candidates else 1
    plausible = []
    for stage, cands in (("screened", candidates), ("first order", [first_order(family, nk)])):
        for o in cands:
            if stage != "screened" and o in candidates:
                continue
            try:
                r = fitter.run(data, family, o, **kw)
            except ConfigError:
                raise           # a wrong option is the caller's, not a candidate's, failure
            except JThermoError as exc:
                path.append(f"{family} {_orders_text(o)}: refused ({exc})")
                continue
            chk = heat_check(r.model, data)
            if not chk["plausible"]:
                path.append(f"{family} {_orders_text(o)}: implausible ({chk['warnings'][0]})")
                continue
            p = n_params_per_output(family, o, data.n_inputs, data.n_outputs) * data.n_outputs
            v = _criterion(r, data, p, criterion)
            path.append(f"{family} {_orders_text(o)}: plausible, {criterion} {v:.4g}")
            plausible.append((v, len(plausible), r))
        if plausible:
            break
    if plausible:
        return min(plausible, key=lambda t: t[:2])[2], path, table
    r = constrained_polynomial(data, family)
    chk = heat_check(r.model, data)
    path.append(f"{family} {_orders_text(r.orders)}: constrained first order (positive "
                "gains, pole in (0, 1))" + ("" if chk["plausible"] else f", {chk['warnings'][0]}"))
    pos, sub = positive_as_polynomial(data, family, criterion)
    if pos is None:
        path.extend(sub[-1:])
        return r, path, table
    pos_chk = heat_check(pos.model, data)
    path.append(f"{family} {_orders_text(pos.orders)}: the positive state space n="
                f"{pos.orders['nb']} as polynomials" + ("" if pos_chk["plausible"]
                                                       else f", {pos_chk['warnings'][0]}"))
    if not pos_chk["plausible"]:
        return r, path, table
    fits = [_mean_fit(m.model.to_statespace(), data) for m in (r, pos)]
    if chk["plausible"] and fits[0] >= fits[1]:
        path.append(f"constrained first order kept: fit {fits[0]:.1f} % against {fits[1]:.1f} %")
        return r, path, table
    path.append(f"positive state space chosen: fit {fits[1]:.1f} %"
                + (f" against {fits[0]:.1f} %" if chk["plausible"] else ""))
    return pos, path, table


def greybox_options(data: IOData, kw: dict) -> dict:
    """`use_signals` for the greybox model: the first measured signal is its surroundings only
    when named so (a fan command is no temperature); fitted surroundings are bounded by the
    lowest recorded temperature (`fit_greybox`'s `surroundings_max`)."""
    if "use_signals" not in kw and data.w.shape[1]:
        name = data.signal_names[0].lower()
        kw = {**kw, "use_signals": any(wd in name for wd in SURROUNDINGS_WORDS)}
    if "surroundings_max" not in kw:
        kw = {**kw, "surroundings_max": float(np.min(np.asarray(data.y)))}
    return kw


def fit_greybox_heat(data: IOData, fitter, **kw) -> tuple[FitResult, list]:
    """The greybox bed on the heat path: measured surroundings where a signal is named so,
    else a fitted constant below the coldest reading (`greybox_options`); where measured
    surroundings give a model that does not pass `heat_check` (a room sensor that is no
    zone's surroundings), the fitted, bounded constant instead."""
    opts = greybox_options(data, kw)
    r = fitter.run(data, "greybox", None, **opts)
    chk = heat_check(r.model, data)
    where = ("surroundings measured" if r.model.n_signals else
             "surroundings fitted" + (", bounded by the coldest reading"
                                      if r.extra.get("surroundings_bounded") else ""))
    path = [f"greybox: {where}" + ("" if chk["plausible"] else f", {chk['warnings'][0]}")]
    if chk["plausible"] or not r.model.n_signals or "use_signals" in kw:
        return r, path
    alt = fitter.run(data, "greybox", None, **{**opts, "use_signals": False})
    alt_chk = heat_check(alt.model, data)
    path.append("greybox: surroundings fitted" + (
        ", bounded by the coldest reading" if alt.extra.get("surroundings_bounded") else "")
        + ("" if alt_chk["plausible"] else f", {alt_chk['warnings'][0]}"))
    return (alt, path) if alt_chk["plausible"] else (r, path)


def with_report(res: FitResult, data: IOData, path: list, dropped: dict) -> FitResult:
    """`res` with `extra["physics"]`: the mode, the selection path, what was left out, the
    final verdict and the inputs / signals the model takes."""
    chk = heat_check(res.model, data)
    if dropped.get("rest_samples"):
        path = [f"step from rest: {dropped['rest_samples']} samples of rest put before the "
                "record", *path]
    info = {"mode": "heat", "path": path, **dropped, "plausible": chk["plausible"],
            "warnings": chk["warnings"], "inputs": list(data.input_names),
            "signals": list(data.signal_names)}
    return dataclasses.replace(res, extra={**(res.extra or {}), "physics": info})


__all__ = ["PHYSICS", "SURROUNDINGS_WORDS", "constrained_polynomial", "first_order",
           "fit_greybox_heat", "fit_polynomial_heat", "fit_ss_heat", "greybox_options", "heat_data",
           "positive_as_polynomial", "positive_polynomial", "rest_before", "with_report"]
