"""State-space estimation: N4SID start, then prediction-error refinement.

The MATLAB `ssest` recipe (Ljung 1999, §10.6): a subspace estimate (`n4sid`, several weightings
and horizons as multi-start points) is moved to the basis $C = [I\\;0]$ and refined by
minimising the simulation error (`focus="simulation"`, the default: K = 0, an output-error
model) or the mean squared one-step prediction error (`focus="prediction"`, K estimated) with
Levenberg–Marquardt (`jthermo.identify.pem.minimize`). The initial state is estimated with the
other parameters. Simulation is the default because the validation figure a thermal bed's user
reads is a simulation fit, and with the innovations model of order n the noise model shares the
plant's poles: coloured sensor noise (a pole of its own) then biases the prediction-focus plant.
Simulation focus narrows the validation fit's gap to the true model at every N from 4 to 19
on a linear N-zone bed with AR(1) sensor noise, and raises the real recordings' fits (measured
by `python experiments/ss_focus_scale.py`).

One state per output (n = ny, C = I, simulation focus, initial state estimated): the gap left
at N ≥ 9 by full A was variance, not an early stop: the true structure (diagonal A: zones
coupled only through the heaters) fitted by the same PEM simulates better than full A, whose
estimation error is the lower (measured by `python experiments/scale_fit_checks.py ss --n 9`).
The default (`coupling="auto"`) therefore
fits diagonal A first, each output its own first-order problem given the inputs
(`fit_diagonal`: N small problems in one compiled call), and keeps it unless full A, refined from it on the first
two thirds of the record, simulates the last third better (`coupling_holdout`); then full A is
refined from the diagonal fit on the whole record. With automatic orders this narrows the gap
to the true model at N = 4 to 19 (diagonal A chosen at every N), and the real recordings fit as
well as with full A (measured by `python experiments/ss_coupling_scale.py`).
In rest mode (x0 = 0, `rest_coupling`) the same structure with x0 fixed at 0: closer to the true
model at N = 9 and 16, and on the real recordings no worse (where the hold-out keeps full A);
x0 estimated instead costs the short recordings several points (measured by
`python experiments/ss_rest_structure.py`).
The returned model is stable (A's eigenvalues are projected inside the unit circle if the
optimum lies outside it).

Scale: when the dense Jacobians of all starts (T·ny × p each) would exceed
`DENSE_JACOBIAN_BYTES` (at N = 16 zones: 96 000 residuals × ~800 parameters), the PEM runs
from the first N4SID estimate alone with matrix-free Gauss–Newton
(`jthermo.identify.matrix_free.minimize_matrix_free`, at most `MATRIX_FREE_STEPS` steps; `converged`
says whether the cap cut it short, and the covariance is NaN).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..data import IOData, require_excitation, split
from ..errors import FitError, JThermoError, ModelError
from ..models.statespace import InnovationsSS, innovations, pack, unpack
from .matrix_free import minimize_matrix_free
from .operating_point import OPERATING_POINTS
from .pem import PEMResult, minimize, minimize_many
from .result import FitResult, register_fitter
from .subspace import choose_order, default_horizon, n4sid, n4sid_variants

FOCUS = ("prediction", "simulation")
#: state coupling when n = ny (one state per output, C = I) in simulation focus
COUPLING = ("auto", "diagonal", "full")

#: above this many bytes of dense Jacobian (all starts, T·ny × p float64) the PEM runs from the
#: best N4SID start alone with matrix-free Gauss–Newton (`minimize_matrix_free`): at N = 16
#: zones the dense Jacobian of 4 starts is 2.5 GB and the solve took 12 GB
DENSE_JACOBIAN_BYTES = 256 * 2**20
#: step cap of the matrix-free solve (its `converged` flag says whether the cap cut it short)
MATRIX_FREE_STEPS = 30


def ss_residuals(theta: Float[Array, " p"], args: Any) -> Float[Array, "T ny"]:
    """PEM residuals of an innovations state space: theta = [pack(model), x0].

    `args = (template, y, du, dw)`: `template` an `InnovationsSS` fixing the structure and the
    operating point, `y` absolute outputs, `du`, `dw` input and signal deviations.
    """
    template, y, du, dw = args
    p = template.n_params()
    model = unpack(theta[:p], template)
    return innovations(model, y, du, dw, theta[p:])


def ss_residuals_offset(theta: Float[Array, " p"], args: Any) -> Float[Array, "T ny"]:
    """As `ss_residuals` with the output operating point estimated too: theta = [pack, x0, dy0]."""
    template, y, du, dw = args
    p, nx, ny = template.n_params(), template.A.shape[0], template.C.shape[0]
    model = unpack(theta[:p], template)
    return innovations(model, y - theta[p + nx:p + nx + ny], du, dw, theta[p:p + nx])


def ss_residuals_level(theta: Float[Array, " p"], args: Any) -> Float[Array, "T ny"]:
    """As `ss_residuals` with x0 = 0 and the output level estimated: theta = [pack, dy0]."""
    template, y, du, dw = args
    p = template.n_params()
    model = unpack(theta[:p], template)
    return innovations(model, y - theta[p:], du, dw, None)


def ss_cost(theta: Float[Array, " p"], args: Any) -> Float[Array, ""]:
    """Mean squared residual $V(\\theta) = \\frac{1}{T n_y}\\sum \\|\\varepsilon\\|^2$."""
    return jnp.mean(ss_residuals(theta, args) ** 2)


def diagonal_residual(theta: Float[Array, " p"], args: Any) -> Float[Array, "T 1"]:
    """Simulation error of one output of a model with diagonal A (one state per output, C = I):
    theta = [a, b (nu), bw (nw), x0, dy0], or [a, b, bw, dy0] with x0 = 0 (a record that
    starts at rest; told apart by the length of theta).

    $\\hat y_k = dy_0 + x_k$, $x_{k+1} = a x_k + b^\\top \\tilde u_k + b_w^\\top \\tilde w_k$:
    given the inputs, each output is its own first-order problem (`args`: `y` the output's
    deviation `(T,)`, `du (T, nu)`, `dw (T, nw)`)."""
    y, du, dw = args["y"], args["du"], args["dw"]
    nu, nw = du.shape[1], dw.shape[1]
    drive = du @ theta[1:1 + nu] + dw @ theta[1 + nu:1 + nu + nw]
    x0 = theta[1 + nu + nw] if theta.shape[0] == 3 + nu + nw else jnp.zeros((), theta.dtype)

    def body(x, d):
        return theta[0] * x + d, x

    _, xs = jax.lax.scan(body, x0, drive)
    return (y - theta[-1] - xs)[:, None]


def diagonal_start(ydev: np.ndarray, du: np.ndarray, dw: np.ndarray) -> np.ndarray:
    """Per-output first-order ARX least squares, `(ny, 3 + nu + nw)` rows
    [a, b, bw, x0 = y(0), dy0 = 0]: $y_{k+1} = a y_k + b^\\top \\tilde u_k + b_w^\\top
    \\tilde w_k + c$ (c absorbs the level; a is clipped into [0, 0.9995])."""
    X = np.column_stack([du[:-1], dw[:-1], np.ones(len(du) - 1)])
    rows = []
    for i in range(ydev.shape[1]):
        coef = np.linalg.lstsq(np.column_stack([ydev[:-1, i], X]), ydev[1:, i], rcond=None)[0]
        a = float(np.clip(coef[0], 0.0, 0.9995))
        rows.append(np.concatenate([[a], coef[1:-1], [ydev[0, i], 0.0]]))
    return np.stack(rows)


def fit_diagonal(ydev, du, dw, max_steps: int = 100, free_x0: bool = True):
    """Simulation-error PEM of the diagonal-A model from `diagonal_start`: the outputs' problems
    one after another in one compiled call (`minimize_many`, `batch="map"`: Jacobians of
    `(T, 3 + nu + nw)`, never the joint one). `free_x0=False`: x0 = 0 (the record starts at
    rest), the x0 column left out. Returns `(PEMResult, theta (ny, 3 + nu + nw))` (one column
    fewer without x0)."""
    ydev, du, dw = (jnp.asarray(a) for a in (ydev, du, dw))
    ny, nu, nw = ydev.shape[1], du.shape[1], dw.shape[1]
    start = diagonal_start(np.asarray(ydev), np.asarray(du), np.asarray(dw))
    if not free_x0:
        start = np.delete(start, 1 + nu + nw, axis=1)
    args = {"y": ydev.T, "du": jnp.broadcast_to(du, (ny,) + du.shape),
            "dw": jnp.broadcast_to(dw, (ny,) + dw.shape)}
    res = minimize_many(diagonal_residual, jnp.asarray(start, ydev.dtype), args,
                        max_steps=max_steps, throw=False, batch="map")
    return res, res.theta


def diagonal_theta(template: InnovationsSS, y, du, dw, max_steps: int = 100,
                   free_x0: bool = True):
    """The diagonal-A fit (`fit_diagonal`) in `ss_residuals_offset`'s layout
    `[pack(template with A = diag(a), B, Bw), x0, dy0]` (`free_x0=False`: x0 = 0, in
    `ss_residuals_level`'s layout `[pack, dy0]`), its per-output `PEMResult` and the
    covariance of that vector (block diagonal by output; zero for the fixed off-diagonal A)."""
    res, th = fit_diagonal(y - template.y0, du, dw, max_steps, free_x0)
    n, nu, nw = th.shape[0], du.shape[1], dw.shape[1]
    m = eqx.tree_at(lambda m: (m.A, m.B, m.Bw), template,
                    (jnp.diag(th[:, 0]), th[:, 1:1 + nu], th[:, 1 + nu:1 + nu + nw]))
    theta = jnp.concatenate([pack(m), th[:, 1 + nu + nw:].T.ravel()])
    # where each output's [a, b, bw, (x0), dy0] sits in theta (A, B, Bw row-major, then x0, dy0)
    p = m.n_params()
    i = np.arange(n)[:, None]
    tail = [p + i, p + n + i] if free_x0 else [p + i]
    idx = np.concatenate([i * (n + 1), n * n + i * nu + np.arange(nu),
                          n * n + n * nu + i * nw + np.arange(nw), *tail], axis=1)
    cov = np.zeros((theta.size, theta.size))
    zc = np.asarray(res.covariance)
    for k in range(n):
        cov[np.ix_(idx[k], idx[k])] = zc[k]
    return theta, res, cov


def coupling_holdout(data: IOData, template: InnovationsSS, refine, fraction: float = 2 / 3,
                     max_steps: int = 100, free_x0: bool = True) -> dict:
    """Do the data show coupling between the states (n = ny, C = I)? Both structures are fitted
    on the first `fraction` of `data` (diagonal A by `diagonal_theta`, x0 estimated or 0 as
    `free_x0`; full A by `refine` from it) and simulated on the rest with the least-squares
    initial state (`simulation_error`). Returns `{"diagonal": err, "full": err}` (sums of
    squares)."""
    first, rest = split(data, fraction)
    y, du, dw = _deviations(first, template)
    th_d, _, _ = diagonal_theta(template, y, du, dw, max_steps, free_x0)
    th_f = refine(th_d, (template, y, du, dw)).theta
    return {name: simulation_error(_offset_model(th, template).to_statespace(), rest)
            for name, th in (("diagonal", th_d), ("full", th_f))}


def _deviations(data: IOData, template: InnovationsSS):
    dtype = template.A.dtype
    return (jnp.asarray(data.y, dtype), jnp.asarray(data.u, dtype) - template.u0,
            jnp.asarray(data.w, dtype) - template.w0)


def _offset_model(theta, template: InnovationsSS) -> InnovationsSS:
    """The model of `ss_residuals_offset`'s theta `[pack, x0, dy0]`, its level in `y0`."""
    p, ny = template.n_params(), template.C.shape[0]
    model = unpack(theta[:p], template)
    return eqx.tree_at(lambda m: m.y0, model, template.y0 + theta[theta.size - ny:])


def simulation_error(ss, data: IOData, free_x0: bool = True) -> float:
    """Sum of squared simulation errors $\\sum_t \\|y_t - \\hat y_{sim}(t)\\|^2$ on `data`,
    with the least-squares initial state (`free_x0`) or from rest (x0 = 0, the output level
    fitted by least squares) (NumPy)."""
    A, C = np.asarray(ss.A), np.asarray(ss.C)
    w = data.w if ss.Bw.shape[1] else None
    y_free = np.asarray(ss.simulate(data.u, w))
    O = np.empty((data.n_samples, C.shape[0], A.shape[0]))
    M = C.copy()
    for k in range(data.n_samples):
        O[k] = M
        M = M @ A
    r = data.y - y_free
    if not free_x0:
        err = float(np.sum((r - r.mean(axis=0)) ** 2))
        return err if np.isfinite(err) else float("inf")
    r = r.ravel()
    Om = O.reshape(-1, A.shape[0])
    x0 = np.linalg.lstsq(Om, r, rcond=None)[0]
    err = float(np.sum((r - Om @ x0) ** 2))
    return err if np.isfinite(err) else float("inf")


def choose_operating_point(data: IOData, n: int, horizon: int | None = None) -> str:
    """`"mean"` or `"rest"`: whichever N4SID estimate simulates the estimation data better
    (mean: with the least-squares initial state; rest: from rest, x0 = 0)."""
    errs = {}
    for op in OPERATING_POINTS:
        try:
            errs[op] = simulation_error(n4sid(data, n, horizon, operating_point=op)[0], data,
                                  free_x0=op == "mean")
        except JThermoError:
            errs[op] = float("inf")
    return min(errs, key=errs.get)


def _starts(data: IOData, n: int, n_starts: int, seed: int, output_error: bool,
            horizon: int | None, operating_point: str = "mean"):
    """Distinct N4SID estimates (CVA/MOESP × horizons), in the common canonical structure."""
    i0 = (default_horizon(n, data.n_outputs, data.n_samples, data.n_inputs + data.w.shape[1])
          if horizon is None else int(horizon))
    models = []
    for i in (i0, 2 * i0, max(2, i0 // 2)):
        if len(models) >= n_starts:
            break
        try:
            out = n4sid_variants(data, n, horizon=i, operating_point=operating_point)
        except JThermoError:  # a longer horizon may not fit the data: just fewer starts
            if not models:
                raise
            continue
        models += [InnovationsSS.from_statespace(ss, output_error=output_error) for ss, _ in out]
    models = models[:max(1, n_starts)]
    ref = models[0]
    thetas = [np.asarray(pack(m)) for m in models if m.fixed_c == ref.fixed_c]
    rng = np.random.default_rng(seed)
    while len(thetas) < n_starts:   # perturbations of the first start fill the batch
        thetas.append(thetas[0] * (1.0 + 0.02 * rng.standard_normal(thetas[0].shape)))
    return ref, np.stack(thetas)


def fit_statespace(data: IOData, n: int | None = None, *, seed: int = 0, n_starts: int = 4,
                   focus: str = "simulation", horizon: int | None = None, max_steps: int = 100,
                   solver: str = "lm", covariance: bool = True, estimate_x0: bool | None = None,
                   max_order: int | None = None, operating_point: str = "auto",
                   screen_steps: int = 10, coupling: str = "auto", rest_coupling: str = "auto"):
    """Estimate an innovations state space of order `n` by N4SID + PEM.

    $\\hat\\theta = \\arg\\min \\frac{1}{T n_y}\\sum_t \\|y_t - \\hat y(t;\\theta)\\|^2$
    over A, B, (C), Bw, $x_0$ (and K with prediction focus, $\\hat y(t|t-1)$)
    (Ljung 1999, §7.3 and §10.6).

    **Arguments:**
    - `data`: estimation data (inputs, outputs, optional measured signals).
    - `n`: state order; `None` picks it from the Hankel singular values (`choose_order`).
    - `seed`: seeds the perturbed start points that fill the batch beyond the N4SID variants.
    - `n_starts`: start points solved together (N4SID with CVA/MOESP weighting and several
      horizons, then perturbations).
    - `focus`: `"simulation"` (the default: simulation error, K = 0) or `"prediction"`
      (one-step error, K estimated: a noise model for a Kalman predictor).
    - `horizon`, `max_steps`, `solver`, `covariance`: passed to `n4sid` / `minimize`.
    - `estimate_x0`: estimate the initial state and the output level `dy0` (otherwise x0 = 0,
      the operating point, and in mean mode y0 fixed). Default: True in mean mode; False in
      rest mode, whose meaning is x0 = 0 (only the output level `dy0` is estimated).
    - `screen_steps`: solve every start for this many steps, then the best to convergence.
    - `operating_point`: `"mean"` (u0 = the data's means, x0 and the output level estimated),
      `"rest"` (the record starts at rest with zero input: u0 = 0, x0 = 0, the output level
      estimated with the other parameters, starting from y(0)), or
      `"auto"` (whichever N4SID estimate simulates the estimation data better).
    - `coupling`: with one state per output (n = ny, C = I; simulation focus, x0 estimated):
      `"auto"` (diagonal A unless `coupling_holdout` favours full A, see the module notes),
      `"diagonal"` or `"full"` (N4SID starts, full A: the path for any other structure).
      `extra["coupling"]` says which was fitted, `extra["coupling_holdout"]` the hold-out errors.
    - `rest_coupling`: the same choice in rest mode with x0 = 0 (`"auto"`, the default, and
      `"diagonal"`: the diagonal-A fit with x0 = 0; `"full"`: N4SID starts, full A); `coupling`
      `"full"` overrides it.

    **Returns:** a `FitResult` with `model` (a stable `StateSpace`), `orders = {"n": n}`,
    `converged`, `cost` (mean squared residual), `covariance`/`std` of the packed parameters
    `[pack(InnovationsSS), x0, dy0]` (`x0` left out where it is not estimated, `dy0` the
    estimated output offset, left out when neither is estimated; in the basis $C = [I\\;0]$,
    before any eigenvalue projection), and `criterion_table` (the Hankel singular values when
    `n` was chosen automatically).
    """
    import time

    t_start = time.perf_counter()
    for name, value in (("coupling", coupling), ("rest_coupling", rest_coupling)):
        if value not in COUPLING:
            raise ModelError(f"fit_statespace: {name} must be one of {', '.join(COUPLING)}, "
                             f"got {value!r}")
    if focus not in FOCUS:
        raise ModelError(f"fit_statespace: focus must be one of {', '.join(FOCUS)}, got {focus!r}")
    if int(n_starts) < 1:
        raise ModelError(f"fit_statespace: n_starts must be >= 1, got {n_starts}")
    require_excitation(data)
    table = None
    if n is None:
        _, svals = n4sid(data, None, horizon=horizon, max_order=max_order)
        n = choose_order(svals, max_order=max_order if max_order is not None
                         else min(len(svals) - 1, 4 * data.n_outputs + 8))
        table = [{"n": k + 1, "hankel_sv": float(s), "chosen": k + 1 == n}
                 for k, s in enumerate(svals)]
    if int(n) != n or n < 1:
        raise ModelError(f"fit_statespace: order n must be a positive integer, got {n!r}")
    n = int(n)
    if operating_point == "auto":
        operating_point = choose_operating_point(data, n, horizon)
    elif operating_point not in OPERATING_POINTS:
        raise ModelError(f"fit_statespace: operating_point must be auto, mean or rest, "
                         f"got {operating_point!r}")
    output_error = focus == "simulation"
    # one start first: its size decides between the dense and the matrix-free solve
    template, theta_m = _starts(data, n, 1, seed, output_error, horizon, operating_point)
    rest = operating_point == "rest"
    if estimate_x0 is None:
        estimate_x0 = not rest
    n_par = template.n_params() + (n if estimate_x0 else 0) + \
        (data.n_outputs if (estimate_x0 or rest) else 0)
    if data.n_samples * data.n_outputs <= n_par:
        raise FitError(f"fit_statespace: {data.n_samples} samples are too few for "
                       f"{n_par} parameters")
    large = int(n_starts) * data.n_samples * data.n_outputs * n_par * 8 > DENSE_JACOBIAN_BYTES
    # one state per output (C = I) in simulation focus: the diagonal-A structure first
    rest_zero = rest and not estimate_x0
    if rest_zero and coupling != "full":
        coupling = rest_coupling
    structured = (coupling != "full" and output_error and (estimate_x0 or rest_zero)
                  and template.fixed_c and n == data.n_outputs and n >= 2)
    structure = {"coupling": "full"}
    full_residuals = ss_residuals_level if rest_zero else ss_residuals_offset

    def refine(theta0, args):
        """Full-A simulation-error PEM from one start (matrix-free unless small)."""
        if args[1].shape[0] * data.n_outputs * n_par * 8 > DENSE_JACOBIAN_BYTES // 8:
            return minimize_matrix_free(full_residuals, theta0, args,
                                        max_steps=min(max_steps, MATRIX_FREE_STEPS))
        return minimize(full_residuals, theta0, args, solver=solver, max_steps=max_steps,
                        covariance=covariance)

    if not large and int(n_starts) > 1 and not structured:
        template, theta_m = _starts(data, n, int(n_starts), seed, output_error, horizon,
                                    operating_point)

    def solve(fn, theta0, args, **kw):
        if large:
            return minimize_matrix_free(fn, theta0[0], args,
                                        max_steps=min(max_steps, MATRIX_FREE_STEPS))
        return minimize(fn, theta0, args, **kw)

    dtype = template.A.dtype
    y = jnp.asarray(data.y, dtype)
    du = jnp.asarray(data.u, dtype) - template.u0
    dw = jnp.asarray(data.w, dtype) - template.w0
    if rest_zero:
        # at rest at u = 0 before the record: x0 = 0, only the output level is estimated
        args = (template, y, du, dw)
        if structured:
            res, structure = _fit_structured(data, template, args, coupling, refine, max_steps,
                                             free_x0=False)
        else:
            theta0 = np.concatenate([theta_m, np.zeros((theta_m.shape[0], data.n_outputs))],
                                    axis=1)
            res = solve(ss_residuals_level, jnp.asarray(theta0, dtype), args, solver=solver,
                        max_steps=max_steps, covariance=covariance, screen_steps=screen_steps)
        theta = res.theta
        p = template.n_params()
        x0 = jnp.zeros(n, dtype)
        template = eqx.tree_at(lambda m: m.y0, template, template.y0 + theta[p:])
    elif estimate_x0:
        # the output level is estimated with x0 in both operating-point modes: a fixed y0 (the
        # data's mean or first sample) is off by the noise's mean or the first noise sample
        # plus, for the mean, the start transient's share, and biases every simulated output
        extra = n + data.n_outputs
        args = (template, y, du, dw)
        if structured:
            res, structure = _fit_structured(data, template, args, coupling, refine, max_steps)
        else:
            theta0 = np.concatenate([theta_m, np.zeros((theta_m.shape[0], extra))], axis=1)
            res = solve(ss_residuals_offset, jnp.asarray(theta0, dtype), args, solver=solver,
                        max_steps=max_steps, covariance=covariance, screen_steps=screen_steps)
        theta = res.theta
        p = template.n_params()
        x0 = theta[p:p + n]
        template = eqx.tree_at(lambda m: m.y0, template, template.y0 + theta[p + n:])
    else:
        args = (template, y, du, dw)
        res = solve(_ss_residuals_x0zero, jnp.asarray(theta_m, dtype), args, solver=solver,
                       max_steps=max_steps, covariance=covariance, screen_steps=screen_steps)
        theta = res.theta
        x0 = jnp.zeros(n, dtype)
    model = unpack(theta[:template.n_params()], template)
    if not bool(jnp.all(jnp.isfinite(theta))):
        raise FitError("fit_statespace: the estimate is not finite")
    model = model.stabilized()
    ss = model.to_statespace()
    return FitResult(model=ss, orders={"n": n}, converged=bool(res.converged),
                   cost=float(res.cost), covariance=res.covariance, std=res.std,
                   criterion_table=table, x0=x0, family="ss",
                   seconds=time.perf_counter() - t_start,
                   extra={"start_costs": np.asarray(res.start_costs), "n_steps": int(res.n_steps),
                          "parametrised": model, "operating_point": operating_point,
                          **structure})


def _fit_structured(data: IOData, template: InnovationsSS, args, coupling: str, refine,
                    max_steps: int, free_x0: bool = True) -> tuple[PEMResult, dict]:
    """Diagonal A (`diagonal_theta`), or, with `coupling="auto"` when `coupling_holdout`
    favours it, full A refined from it by `refine`; returns the result in
    `ss_residuals_offset`'s layout (`free_x0=False`: `ss_residuals_level`'s) and what was
    chosen (`extra["coupling"]`)."""
    _, y, du, dw = args
    th_d, res_d, cov = diagonal_theta(template, y, du, dw, max_steps, free_x0)
    info = {"coupling": "diagonal"}
    if coupling == "auto":
        err = coupling_holdout(data, template, refine, max_steps=max_steps, free_x0=free_x0)
        info["coupling_holdout"] = err
        if err["full"] < err["diagonal"]:
            return refine(th_d, args), {**info, "coupling": "full"}
    cost = jnp.mean(res_d.cost)
    steps = jnp.max(res_d.n_steps)
    return PEMResult(theta=th_d, cost=cost, converged=jnp.all(res_d.converged), n_steps=steps,
                     start_costs=cost[None], covariance=jnp.asarray(cov),
                     std=jnp.sqrt(jnp.clip(jnp.diagonal(jnp.asarray(cov)), 0.0)),
                     best_start=jnp.asarray(0), start_steps=steps[None],
                     expected_improvement=jnp.max(res_d.expected_improvement)), info


def _ss_residuals_x0zero(theta, args):
    template, y, du, dw = args
    return innovations(unpack(theta, template), y, du, dw, None)


@register_fitter(("ss",), options=fit_statespace)
def fit_statespace_family(data: IOData, family: str, orders: dict | None, *, seed: int = 0,
                          n_starts: int = 4, progress=None, **kw) -> FitResult:
    """`fit`'s fitter of the family `ss`: `fit_statespace` of order `orders["n"]` (None: the
    order is chosen from the Hankel singular values) with options `kw`."""
    del family, progress
    return fit_statespace(data, None if orders is None else orders["n"], seed=seed,
                          n_starts=n_starts, **kw)


__all__ = [
    "COUPLING",
    "FOCUS",
    "choose_operating_point",
    "coupling_holdout",
    "diagonal_residual",
    "diagonal_start",
    "diagonal_theta",
    "fit_diagonal",
    "fit_statespace",
    "fit_statespace_family",
    "simulation_error",
    "ss_cost",
    "ss_residuals",
    "ss_residuals_level",
    "ss_residuals_offset",
]
