"""Validation on data: fit %, least-squares initial states, simulation/prediction comparison
(MATLAB `compare`) and the residual whiteness and independence tests (MATLAB `resid`)."""

from __future__ import annotations

import math
from statistics import NormalDist

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..data import IOData, idle_inputs, same_ts
from ..errors import DataError, ModelError
from ..models import polynomial_numpy, statespace_numpy
from ..models._base import AbstractModel


def is_traced(x) -> bool:
    """True for a JAX tracer (inside jit, vmap or grad): no host-side checks then."""
    return isinstance(x, jax.core.Tracer)


# ---------------------------------------------------------------- fit


def fit_percent(y: ArrayLike, yhat: ArrayLike) -> Float[Array, "*ny"]:
    """Normalised root-mean-square fit per output, in %.

    $\\mathrm{fit}_i = 100 \\, (1 - \\lVert y_i - \\hat y_i \\rVert / \\lVert y_i - \\bar y_i \\rVert)$,
    100 for a perfect model, 0 for the mean, negative for worse (MATLAB `goodnessOfFit` 'NRMSE').

    **Arguments:** `y`, `yhat`: `(T, ny)` (or `(T,)`) measured and modelled outputs.

    **Returns:** `(ny,)` fit per output (a 0-d array for 1-D input).
    """
    y = jnp.asarray(y)
    yhat = jnp.asarray(yhat)
    if y.shape != yhat.shape:
        raise DataError(f"fit_percent: y has shape {y.shape} but yhat has shape {yhat.shape}")
    if y.ndim not in (1, 2) or y.shape[0] < 2:
        raise DataError(f"fit_percent: expected (T,) or (T, ny) with T >= 2, got shape {y.shape}")
    num = jnp.linalg.norm(y - yhat, axis=0)
    den = jnp.linalg.norm(y - jnp.mean(y, axis=0), axis=0)
    if not is_traced(den):
        _refuse_flat(np.asarray(_flat(den, y, jnp)))
    return 100.0 * (1.0 - num / den)


# ---------------------------------------------------------------- inputs and initial state


def _check_io(model: AbstractModel, data: IOData, what: str):
    if not isinstance(data, IOData):
        raise DataError(f"{what}: expected IOData, got {type(data).__name__}")
    if not isinstance(model, AbstractModel):
        raise ModelError(f"{what}: expected a jthermo model, got {type(model).__name__}")
    if data.n_inputs != model.n_inputs:
        raise DataError(f"{what}: the data have {data.n_inputs} input(s), the model {model.n_inputs}")
    if data.n_outputs != model.n_outputs:
        raise DataError(f"{what}: the data have {data.n_outputs} output(s), the model {model.n_outputs}")
    if not same_ts(model.ts, data.ts):
        raise DataError(f"{what}: the data's sample time {data.ts:g} s is not the model's "
                        f"{model.ts:g} s")
    nw = model.n_signals
    if data.w.shape[1] < nw:
        raise DataError(f"{what}: the model needs {nw} measured signal(s) w, the data have {data.w.shape[1]}")
    u = jnp.asarray(data.u)
    y = jnp.asarray(data.y)
    w = jnp.asarray(data.w[:, :nw]) if nw else None
    return y, u, w


@eqx.filter_jit
def _sim(model, u, w, x0):
    return model.simulate(u, w, x0)


@eqx.filter_jit
def _pred(model, y, u, w, x0, k):
    return model.predict(y, u, w, k, x0)


def _response(model, y, u, w, x0, k):
    return _sim(model, u, w, x0) if k is None else _pred(model, y, u, w, x0, k)


@eqx.filter_jit
def _ls_initial_state(model, y, u, w, x_ref, k):
    """Least squares on $y = f(x_0)$, exact when f is affine in $x_0$ (every linear model)."""
    f = (lambda x0: model.simulate(u, w, x0)) if k is None else \
        (lambda x0: model.predict(y, u, w, k, x0))
    y_ref = f(x_ref)
    O = jax.jacfwd(f)(x_ref)                       # (n, ny, nx)
    n, ny, nx = O.shape
    rhs = (y - y_ref).reshape(n * ny)
    O = O.reshape(n * ny, nx)
    # column-scaled normal equations: a tall SVD/QR costs ~20x more on CPU, and the
    # squared condition number is harmless in float64 for the few states of these models
    scale = jnp.sqrt(jnp.sum(O ** 2, axis=0))
    scale = jnp.where(scale > 0, scale, 1.0)
    On = O / scale
    dx = jnp.linalg.lstsq(On.T @ On, On.T @ rhs)[0] / scale
    y_lin = y_ref + (O @ dx).reshape(n, ny)          # the prediction of the affine model
    return x_ref + dx, y_lin


_GAUSS_NEWTON_STEPS = 8


def estimate_initial_state(model: AbstractModel, data: IOData, n: int | None = None, *,
                           k: int | None = None) -> Float[Array, " nx"]:
    """Least-squares initial state from the first `n` samples (default: all).

    The model's output is affine in the initial state, $y = \\mathcal{O} x_0 + G u$, so
    $\\hat x_0 = \\arg\\min \\lVert y - \\mathcal{O} x_0 - G u \\rVert$ with $\\mathcal{O}$ taken
    as the Jacobian of the simulation (or of the k-step predictor, for `k` an int). For a
    nonlinear model (the output is not what the affine fit predicted) a few Gauss–Newton steps
    follow, and the estimate is kept only if it simulates the first `n` samples better than
    `model.initial_state(y[0])`, the steady state consistent with the first measurement.
    """
    y, u, w = _check_io(model, data, "estimate_initial_state")
    T = y.shape[0]
    n = T if n is None else int(n)
    if not 1 <= n <= T:
        raise DataError(f"estimate_initial_state: n must lie in [1, {T}], got {n}")
    ys, us = y[:n], u[:n]
    ws = None if w is None else w[:n]
    x_fallback = model.initial_state(y[0])
    x_ls, y_lin = _ls_initial_state(model, ys, us, ws, jnp.zeros_like(x_fallback), k)
    if not bool(jnp.all(jnp.isfinite(x_ls))):
        return x_fallback
    y_ls = _response(model, ys, us, ws, x_ls, k)
    e_ls = jnp.sum((ys - y_ls) ** 2)
    tol = math.sqrt(float(jnp.finfo(ys.dtype).eps)) * (1.0 + jnp.max(jnp.abs(ys)))
    if not bool(jnp.max(jnp.abs(y_ls - y_lin)) <= tol):
        # not affine in x0: a few Gauss-Newton steps, each kept only while it helps
        for _ in range(_GAUSS_NEWTON_STEPS):
            x_new, _ = _ls_initial_state(model, ys, us, ws, x_ls, k)
            if not bool(jnp.all(jnp.isfinite(x_new))):
                break
            e_new = jnp.sum((ys - _response(model, ys, us, ws, x_new, k)) ** 2)
            if not bool(e_new < e_ls):
                break
            x_ls, e_ls = x_new, e_new
    e_fb = jnp.sum((ys - _response(model, ys, us, ws, x_fallback, k)) ** 2)
    return x_ls if bool(e_ls <= e_fb) else x_fallback


def _initial_state(model, data, x0, k, y):
    if isinstance(x0, str):
        if x0 == "estimate":
            return estimate_initial_state(model, data, k=k)
        if x0 == "zero":
            return jnp.zeros_like(model.initial_state(None))
        if x0 == "steady":
            return model.initial_state(y[0])
        raise DataError(f"x0 must be 'estimate', 'zero', 'steady' or an array, got {x0!r}")
    x0 = jnp.asarray(x0)
    want = model.initial_state(None).shape
    if x0.shape != want:
        raise DataError(f"x0 has shape {x0.shape}, the model's state has shape {want}")
    return x0


def compare(model: AbstractModel, data: IOData, *, k: int | None = None,
            x0: str | ArrayLike = "estimate") -> dict:
    """Simulation (`k=None`) or k-step-ahead prediction fit of `model` on `data`, like MATLAB `compare`.

    **Arguments:**
    - `model`: any `AbstractModel`; it receives `data.u` and the first `model.n_signals`
      columns of `data.w`.
    - `k`: prediction horizon in samples, or None for pure simulation.
    - `x0`: `"estimate"` (least squares, see `estimate_initial_state`), `"zero"`, `"steady"`
      (`model.initial_state(y[0])`) or an explicit state.

    **Returns:** a dict with `fit_percent` (list per output), `mean_fit_percent`, `yhat`
    (`(T, ny)` NumPy array), `x0` and `k`.
    """
    y, u, w = _check_io(model, data, "compare")
    if k is not None and (not isinstance(k, (int, np.integer)) or isinstance(k, bool) or k < 1):
        raise DataError(f"compare: k must be a positive integer or None, got {k!r}")
    k = None if k is None else int(k)
    fast = k is None and isinstance(x0, str) and x0 == "estimate"
    if fast and polynomial_numpy.supported(model):
        # NumPy filters: nothing to compile (same result, `polynomial_numpy.initial_state`)
        x_init, yhat = polynomial_numpy.initial_state(model, data.y, data.u)
        fast = bool(np.all(np.isfinite(x_init)))
    elif fast and statespace_numpy.supported(model):
        # one compiled realisation, the rest on the host (`statespace_numpy.initial_state`)
        x_init, yhat = statespace_numpy.initial_state(model, data.y, data.u,
                                                      None if w is None else data.w)
        fast = bool(np.all(np.isfinite(x_init)))
    else:
        fast = False
    if not fast:
        x_init = _initial_state(model, data, x0, k, y)
        yhat = _response(model, y, u, w, x_init, k)
    yhat = np.asarray(yhat)
    if not np.all(np.isfinite(yhat)):
        raise ModelError("compare: the model's response is not finite on these data (unstable model?)")
    fits = np.atleast_1d(fit_percent_np(np.asarray(data.y, np.float64), yhat))
    return {"fit_percent": [float(f) for f in fits], "mean_fit_percent": float(np.mean(fits)),
            "yhat": yhat, "x0": np.asarray(x_init), "k": k}


def _flat(den, y, xp):
    """Outputs whose variation ||y - mean(y)|| is rounding error of ||y|| (1e-12): their fit %
    is a ratio to that error (e.g. -1e291 %), so undefined like an exactly constant one's."""
    return den <= 1e-12 * xp.linalg.norm(y, axis=0)


def _refuse_flat(flat: np.ndarray) -> None:
    """`DataError` naming the first output flagged in `flat` (`_flat`), if any."""
    flat = np.atleast_1d(flat)
    if flat.any():
        raise DataError(f"fit_percent: output {int(np.flatnonzero(flat)[0])} is constant: the fit "
                        "is undefined")


def fit_percent_np(y: np.ndarray, yhat: np.ndarray) -> np.ndarray:
    """`fit_percent` of host arrays in NumPy (no compile), same errors."""
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    _refuse_flat(_flat(den, y, np))
    return 100.0 * (1.0 - np.linalg.norm(y - yhat, axis=0) / den)


def level_offsets(y: ArrayLike, yhat: ArrayLike, names=None) -> list[dict]:
    """Per output, how much of the simulation error is a constant level shift.

    With $e = y - \\hat y$, the mean error $m = \\bar e$ carries the share
    $m^2 / \\overline{e^2}$ of the mean square error, and alone it bounds the fit from above:
    $\\mathrm{fit} \\le 100\\,(1 - |m| / \\sigma_y)$ ($\\sigma_y$ the output's standard
    deviation on the record). An output is flagged (`shifted`) where the shift alone makes the
    fit negative ($|m| > \\sigma_y$) and carries at least half the error: the record sits at
    another level than the model predicts from its inputs (another operating point or
    surroundings, a sensor offset), which a model without an input for it cannot follow.

    **Returns:** one dict per output: `output`, `mean_error` (°C, measured minus simulated),
    `share` of the mean square error, `output_std`, `shifted`."""
    y, yhat = np.asarray(y, np.float64), np.asarray(yhat, np.float64)
    e = y - yhat
    m = e.mean(axis=0)
    mse = np.mean(e ** 2, axis=0)
    sd = y.std(axis=0)
    names = list(names) if names is not None else [f"y{i + 1}" for i in range(y.shape[1])]
    return [{"output": str(n), "mean_error": float(mi), "share": float(mi ** 2 / ms) if ms > 0 else 0.0,
             "output_std": float(si), "shifted": bool(abs(mi) > si and mi ** 2 >= 0.5 * ms)}
            for n, mi, ms, si in zip(names, m, mse, sd)]


def level_offset_notes(offsets: list[dict]) -> list[str]:
    """One line for the flagged outputs of `level_offsets` (none when no output is)."""
    bad = [o for o in offsets if o["shifted"]]
    if not bad:
        return []
    parts = ", ".join(f"{o['output']} {o['mean_error']:+.3g} ({100 * o['share']:.0f} % of its "
                      f"squared error; its standard deviation {o['output_std']:.3g})" for o in bad)
    return [f"the record sits at another level than the model simulates: mean error {parts}; "
            "the fit is low because of that shift (another operating point or surroundings, "
            "or a sensor offset, which the model has no input for), not the dynamics alone"]


# ---------------------------------------------------------------- residual analysis


def cross_covariance(a, b, max_lag):
    """Biased cross-covariance $R_{ab}(\\tau) = \\frac1N \\sum_t a_{t+\\tau} b_t$ for
    $\\tau = -M..M$, all column pairs: `(2M+1, na, nb)`. Inputs are mean-removed."""
    N = a.shape[0]
    nfft = 1 << math.ceil(math.log2(2 * N))
    A = jnp.fft.rfft(a, n=nfft, axis=0)
    B = jnp.fft.rfft(b, n=nfft, axis=0)
    r = jnp.fft.irfft(A[:, :, None] * jnp.conj(B)[:, None, :], n=nfft, axis=0) / N
    lags = jnp.arange(-max_lag, max_lag + 1)
    return r[lags % nfft]


@eqx.filter_jit
def correlations(e: Float[Array, "T ny"], u: Float[Array, "T nu"], max_lag: int):
    """Normalised residual auto-correlation `(M+1, ny)` for lags 0..M and residual–input
    cross-correlation `(2M+1, ny, nu)` for lags −M..M ($\\rho_{eu}(\\tau)$ pairs $e_{t+\\tau}$
    with $u_t$: positive lags test the effect of past inputs)."""
    e = e - jnp.mean(e, axis=0)
    u = u - jnp.mean(u, axis=0)
    see = jnp.sqrt(jnp.mean(e ** 2, axis=0))
    suu = jnp.sqrt(jnp.mean(u ** 2, axis=0))
    Ree = cross_covariance(e, e, max_lag)
    auto = jnp.diagonal(Ree, axis1=1, axis2=2)[max_lag:] / see ** 2
    cross = cross_covariance(e, u, max_lag) / (see[:, None] * suu[None, :])
    return auto, cross


def residual_tests(model: AbstractModel, data: IOData, max_lag: int = 25, alpha: float = 0.01, *,
                   x0: str | ArrayLike = "estimate") -> dict:
    """Whiteness and independence tests of the one-step prediction errors (MATLAB `resid`).

    For a correct model the residuals $\\varepsilon$ are white and uncorrelated with past inputs;
    then each normalised correlation is approximately $N(0, 1/N)$, so the per-lag bound is
    $\\pm z_{1-\\alpha/2}/\\sqrt N$ (plotted, as in MATLAB). The pass/fail decisions control the
    false alarm rate over all lags of a test with a Bonferroni bound $z_{1-\\alpha/(2m)}/\\sqrt N$
    (m lags). The portmanteau statistic is Ljung–Box,
    $Q = N(N+2) \\sum_{\\tau=1}^{M} \\rho_\\varepsilon^2(\\tau)/(N-\\tau) \\sim \\chi^2_M$
    (Ljung 1999, §16.6).

    **Returns:** a dict with `lags_auto` `(M+1,)`, `auto` `(M+1, ny)`, `lags_cross` `(2M+1,)`,
    `cross` `(2M+1, ny, nu)`, `bound`, `bound_auto_family`, `bound_cross_family`,
    `auto_pass` (list per output), `cross_pass` (ny × nu lists), `n_outside_auto`,
    `n_outside_cross`, `ljung_box_q`, `ljung_box_p` (per output), `residuals` `(T, ny)`,
    `whiteness_pass`/`independence_pass` (all outputs/pairs), `n_samples`, `alpha`, `max_lag`.
    An input constant over the record has no cross-correlation: NaN in `cross`, None in
    `cross_pass` and `n_outside_cross`, named in `constant_inputs`; `independence_pass` judges
    the other pairs (None when no input varies).
    """
    y, u, w = _check_io(model, data, "residual_tests")
    N = y.shape[0]
    if not isinstance(max_lag, (int, np.integer)) or isinstance(max_lag, bool) or not 1 <= max_lag < N // 2:
        raise DataError(f"residual_tests: max_lag must be an integer in [1, {N // 2 - 1}], got {max_lag!r}")
    if not (isinstance(alpha, (int, float)) and 0 < alpha < 1):
        raise DataError(f"residual_tests: alpha must lie in (0, 1), got {alpha!r}")
    x_init = _initial_state(model, data, x0, 1, y)
    e = y - _pred(model, y, u, w, x_init, 1)
    if not bool(jnp.all(jnp.isfinite(e))):
        raise ModelError("residual_tests: the residuals are not finite (unstable predictor?)")
    if bool(jnp.any(jnp.std(e, axis=0) == 0)):
        raise DataError("residual_tests: a residual is identically constant: correlations are undefined")
    # a constant input (e.g. a heater held at one level through the record) has no
    # cross-correlation: NaN there, and its pairs are not judged (`cross_pass` None)
    still = np.isin(np.arange(u.shape[1]), idle_inputs(data))
    M = int(max_lag)
    auto, cross = correlations(e, u, M)
    auto = np.asarray(auto)
    c_abs = np.where(still[None, None, :], 0.0, np.abs(np.asarray(cross)))   # judged as nothing
    cross = np.where(still[None, None, :], np.nan, np.asarray(cross))
    nd = NormalDist()
    bound = nd.inv_cdf(1 - alpha / 2) / math.sqrt(N)
    b_auto = nd.inv_cdf(1 - alpha / (2 * M)) / math.sqrt(N)
    b_cross = nd.inv_cdf(1 - alpha / (2 * (2 * M + 1))) / math.sqrt(N)
    a_abs = np.abs(auto[1:])
    taus = np.arange(1, M + 1)
    q = N * (N + 2) * np.sum(auto[1:] ** 2 / (N - taus)[:, None], axis=0)
    p = np.asarray(jax.scipy.special.gammaincc(M / 2.0, jnp.asarray(q) / 2.0))
    auto_pass = (a_abs.max(axis=0) < b_auto)
    cross_pass = (c_abs.max(axis=0) < b_cross)
    judged = np.broadcast_to(~still[None, :], cross_pass.shape)
    return {
        "lags_auto": np.arange(M + 1), "auto": auto,
        "lags_cross": np.arange(-M, M + 1), "cross": cross,
        "bound": bound, "bound_auto_family": b_auto, "bound_cross_family": b_cross,
        "auto_pass": [bool(v) for v in auto_pass],
        "cross_pass": [[bool(v) if ok else None for v, ok in zip(row, jr)]
                       for row, jr in zip(cross_pass, judged)],
        "n_outside_auto": [int(v) for v in (a_abs >= bound).sum(axis=0)],
        "n_outside_cross": [[int(v) if ok else None for v, ok in zip(row, jr)]
                            for row, jr in zip((c_abs >= bound).sum(axis=0), judged)],
        "ljung_box_q": [float(v) for v in q], "ljung_box_p": [float(v) for v in p],
        "whiteness_pass": bool(auto_pass.all()),
        "independence_pass": bool(cross_pass[judged].all()) if judged.any() else None,
        "constant_inputs": [data.input_names[j] for j in np.flatnonzero(still)],
        "residuals": np.asarray(e), "n_samples": N, "alpha": float(alpha), "max_lag": M,
        "input_names": tuple(data.input_names), "output_names": tuple(data.output_names),
    }
