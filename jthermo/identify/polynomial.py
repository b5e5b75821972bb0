"""Polynomial-family fitting (ARX, ARMAX, OE, BJ): `fit_polynomial`, and `fit`'s fitter for them.

Polynomial families are fitted on deviations from an operating point (the data's means, or
rest at zero input: see `fit_polynomial`'s `offset` and `operating_point.py`; stored as the
model's `u0`, `y0`, so `model.simulate(u)` is in absolute units): ARX by linear
least squares, ARMAX/OE/BJ by prediction-error minimisation (Levenberg–Marquardt, one MISO
problem per output, the output rows and their start points solved one after another in one
compiled call, so only one row's Jacobian is held at a time) started
from the ARX estimate and `n_starts - 1` perturbed copies of it; every start gets
`screen_steps` steps and only the best is solved to convergence. C, D and F are parametrised by
reflection coefficients $\\kappa = \\tanh\\rho$, so the returned polynomials are stable.
"""

from __future__ import annotations

import os
from typing import Callable, NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..data import IOData, require_samples
from ..errors import ConfigError, FitError, ModelError
from ..models.polynomial import (
    Polynomial, ar_filter, as_nk, placed, delay_onehot, fir_monic, lagged, poly_from_reflection,
    rational_sum, reflection_from_poly,
)
from .arx import arx_ls, perturb_starts
from .guard import check_model
from .operating_point import (
    OFFSETS, estimate_rest_level, known_rest_level, offset_mode, operating_point,
)
from .pem import minimize_many
from .pem_numpy import EXTEND_ROUNDS, coefficient_jacobian, extend_rows, minimize_rows, step_up
from .result import FitResult, register_fitter

#: the model families `fit_polynomial` serves
POLYNOMIAL_FAMILIES = ("arx", "armax", "oe", "bj")
#: PEM engines of `fit_polynomial`: the measured rule (`choose_engine`), the compiled solve, or
#: NumPy (`pem_numpy`)
ENGINES = ("auto", "jax", "numpy")
#: `choose_engine`: the largest work $w = n_y T p$ (output rows x samples x parameters per row)
#: the NumPy engine takes when two or more cores are free for the compiled one, for rows without
#: a noise model (OE) and with one (ARMAX, BJ: `nc + nd > 0`, whose compiled Jacobian costs
#: more). NumPy uses less CPU up to these sizes; the compiled engine runs on both cores, and on
#: two idle cores it is the faster in wall time for OE above 2.5e6, so OE keeps it there; with a
#: noise model NumPy stays cheaper further (measured cold in fresh processes by
#: `python benchmarks/polynomial_engine_crossover.py`). Beyond: compiled
AUTO_NUMPY_MAX_WORK = 2_500_000
AUTO_NUMPY_MAX_WORK_NOISE = 3_500_000


class PolySpec(NamedTuple):
    """Static structure of one output row's parameter vector."""

    m: int    # number of outputs in the A row (1 diagonal, ny full)
    na: int
    nb: int
    nc: int
    nd: int
    nf: int
    nu: int
    L: int    # largest input lag
    offset: bool = False   # a constant kappa (operating point) is estimated too
    common_f: bool = False   # one F shared by every input of the row

    @property
    def n_f(self) -> int:
        return (1 if self.common_f else self.nu) * self.nf

    @property
    def n_coef(self) -> int:
        return self.m * self.na + self.nu * self.nb + self.nc + self.nd + self.n_f

    @property
    def n_params(self) -> int:
        return self.n_coef + int(self.offset)


def _unpack(theta, s: PolySpec):
    k = 0
    a = theta[k:k + s.m * s.na].reshape(s.m, s.na); k += s.m * s.na
    b = theta[k:k + s.nu * s.nb].reshape(s.nu, s.nb); k += s.nu * s.nb
    c = poly_from_reflection(jnp.tanh(theta[k:k + s.nc])); k += s.nc
    d = poly_from_reflection(jnp.tanh(theta[k:k + s.nd])); k += s.nd
    rho_f = theta[k:k + s.n_f].reshape(1 if s.common_f else s.nu, s.nf)
    f = poly_from_reflection(jnp.tanh(jnp.broadcast_to(rho_f, (s.nu, s.nf))))
    return a, b, c, d, f


def _kappa(theta, s: PolySpec):
    return theta[s.n_coef] if s.offset else jnp.zeros((), theta.dtype)


def poly_residual(theta: Float[Array, " p"], args) -> Float[Array, "T 1"]:
    """One output row's prediction error $\\varepsilon_i = \\frac{D_i}{C_i}\\big((A y)_i -
    \\sum_j \\frac{B_{ij}}{F_{ij}} u_j\\big)$ for `args = (y_i, y_src, u, sel, spec)`.

    `y_i (T,)` this output, `y_src (T, m)` the outputs in its A row, `u (T, nu)` inputs (all
    deviations), `sel (nu, nb, L+1)` the delay selector, `spec` a `PolySpec`; an optional
    sixth entry `mask (p,)` of 0/1 gives the residual of $\\theta \\odot \\mathrm{mask}$: a smaller
    structure embedded in `spec` (`parameter_embedding`, zeros for its missing coefficients) then shares
    `spec`'s compiled solve, its masked parameters with a zero Jacobian column (no step).
    """
    yi, ysrc, u, sel, s = args[:5]
    if len(args) > 5:
        theta = theta * args[5]
    a, b, c, d, f = _unpack(theta, s)
    bl = jnp.einsum("jkl,jk->jl", sel, b)
    w = rational_sum(lagged(u, s.L), bl, f)
    v = yi - _kappa(theta, s)
    if s.na:
        v = v + jnp.einsum("tjk,jk->t", lagged(ysrc, s.na)[:, :, 1:], a)
    return ar_filter(fir_monic(v - w, d), c)[:, None]


def poly_cost(theta: Float[Array, " p"], args) -> Float[Array, ""]:
    """Mean squared prediction error of one output row (what PEM minimises)."""
    return jnp.mean(poly_residual(theta, args) ** 2)


def _atanh_reflection(a: np.ndarray) -> np.ndarray:
    return np.arctanh(reflection_from_poly(a, clip=0.995))


def poly_args(dy, du, spec: PolySpec, nk, full_a: bool):
    T, ny = dy.shape
    nkt = as_nk(nk, ny, du.shape[1])
    dy, du = np.asarray(dy), np.asarray(du)        # laid out in NumPy: nothing to compile
    sel = delay_onehot(nkt, spec.nb, spec.L).astype(dy.dtype)
    yi = np.moveaxis(dy, 1, 0)                                        # (ny, T)
    ysrc = np.broadcast_to(dy[None], (ny,) + dy.shape) if spec.m > 1 else yi[:, :, None]
    ub = np.broadcast_to(du[None], (ny,) + du.shape)
    return tuple(placed(x) for x in (yi, ysrc, ub, sel)) + (spec,)


def fit_polynomial(y: Float[Array, "T ny"], u: Float[Array, "T nu"], *, na: int = 0, nb: int = 1,
                   nc: int = 0, nd: int = 0, nf: int = 0, nk=1, full_a: bool = False,
                   offset: str = "auto", seed: int = 0, n_starts: int = 8, solver: str = "lm",
                   max_steps: int = 200, rtol: float = 1e-6, atol: float = 1e-9, ts: float = 1.0,
                   covariance: bool = True, progress: Callable | None = None,
                   screen_steps: int = 10, batch: str = "map", common_f: bool = False,
                   rest_level=None, shape_orders: dict | None = None, engine: str = "auto",
                   extend_rounds: int = EXTEND_ROUNDS):
    """PEM fit of the polynomial structure to absolute data `y`, `u`.

    Operating point (`offset`): `"mean"` fits deviations from the data's means (`u0`, `y0` =
    means: the record is taken to start at rest there); `"rest"` takes `u0 = 0` and `y0` = the
    level of the first samples (the record starts at rest with zero input, e.g. a cold
    printer; see `estimate_rest_level`);
    `"estimate"` is `"rest"` with `y0` estimated with the other parameters; `"auto"` picks the
    one whose ARX estimate simulates the estimation data best. `rest_level`: the output level
    at rest when it is known (a measured ambient temperature; 0 for data in °C above ambient),
    a number or one per output: `"rest"` with `y0 = rest_level`.

    ARX (nc = nd = nf = 0) is solved in closed form. Otherwise the start is the ARX estimate of
    the same delays: ARMAX gets A, B from ARX (na, nb) and C = 1; OE and BJ get $F_{ij} = A_i$
    and $B_{ij}$ from ARX (nf, nb), and C = D = 1. `n_starts - 1` perturbed copies are added;
    every start is solved for `screen_steps` Levenberg–Marquardt steps and the best one is then
    solved to convergence (`screen_steps=0`: all to convergence). `batch`: `"map"` (default)
    solves the output rows and their start points one after another inside one compiled call
    (`lax.map`): one MISO problem's Jacobian $(T, p)$ is held at a time and each row stops at
    its own step count; `"vmap"` solves all $n_y K$ problems together, which on CPU holds them
    all at once and runs every row to the slowest one's step count (more peak memory and time at
    N = 16, the same fits; measured by `python benchmarks/identification.py`). `common_f`:
    OE/BJ with one denominator per output shared by all its inputs, $y_i = \\sum_j B_{ij}/F_i\\, u_j + \\dots$
    (SIPPY's MIMO structure; a zone with one dominant thermal time constant), instead of
    MATLAB's $F_{ij}$ per input–output pair. `shape_orders`: orders (`na`, `nb`, `nc`, `nd`,
    `nf`) of a larger structure whose compiled PEM solve this fit shares (the fit is that of
    its own orders, the missing coefficients held at zero by a mask: `fit`'s candidates then
    compile once). `engine`: `"jax"` (the compiled `pem.minimize_many`, `solver`, `rtol`,
    `atol`, `batch`), `"numpy"` (`pem_numpy.minimize_rows`, diagonal A only: the same
    residual, starts and screening, nothing compiled, solved until the Gauss–Newton step would
    gain less than `pem_numpy.POLISH_TOL`; `shape_orders` is not needed there) or `"auto"`
    (default: `choose_engine` of the problem's size; `info["engine"]` says which ran).
    `extend_rounds`: with either engine (LM or GN, diagonal A, `covariance`), an output row that
    stops at `max_steps` while its Gauss–Newton step would still gain ≥ 0.01 % of its cost gets
    up to this many further rounds of `max_steps` NumPy LM steps (`pem_numpy.extend_rows`), so
    that a row reported converged is converged and one that is still improving is not cut off
    (0: the step cap is final, the row reported not converged).

    **Returns:** `(model, info)` where `info` has `engine`, `converged` (every output row), `cost`,
    `covariance`, `std`, `start_costs`, `start_steps`, `n_steps`, `offset`, and per output row
    `row_converged` and `expected_improvement` (the relative cost decrease the Gauss–Newton
    step from the result would still give; converged below 1e-4, see `PEMResult`).
    """
    y = placed(y)
    u = placed(u, y.dtype)
    ny, nu = y.shape[1], u.shape[1]
    if offset not in OFFSETS:
        raise ConfigError(f"fit: offset must be one of {', '.join(OFFSETS)}, got {offset!r}")
    nkt = as_nk(nk, ny, nu)
    if engine not in ENGINES:
        raise ConfigError(f"fit: engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    if isinstance(extend_rounds, bool) or not isinstance(extend_rounds, (int, np.integer)) \
            or extend_rounds < 0:
        raise ConfigError(f"fit: extend_rounds must be an integer >= 0, got {extend_rounds!r}")
    if engine == "numpy" and full_a and ny > 1 and nf == 0 and (nc or nd):
        raise ConfigError("fit: engine 'numpy' needs a diagonal A (full_a=False)")
    if engine == "auto":
        n_row = (ny if full_a and ny > 1 else 1) * na + nu * nb + nc + nd + \
            (1 if common_f else nu) * nf
        engine = choose_engine(ny, n_row, y.shape[0], noise_model=bool(nc or nd),
                               full_a=full_a and ny > 1 and nf == 0, solver=solver, batch=batch)
    if full_a and ny > 1 and (nd or nf):
        raise ModelError("fit: a full A matrix polynomial needs nd = nf = 0")
    n_den = na if (nf == 0) else nf
    arx_full = full_a and nf == 0
    if rest_level is not None:
        if offset not in ("auto", "rest"):
            raise ConfigError(f"fit: a known rest_level needs offset 'rest' (or 'auto'), got {offset!r}")
        rest_level, offset = placed(known_rest_level(rest_level, ny), y.dtype), "rest"
    elif offset in ("auto", "rest"):
        rest_level = estimate_rest_level(y, u, nb, nkt, n_den, arx_full, ts)
    if offset == "auto":
        offset = offset_mode(y, u, nb, nkt, n_den, arx_full, ts, rest_level)
    yref, u0, est = operating_point(offset, y, u, rest_level)
    dy, du = np.asarray(y) - yref, np.asarray(u) - u0       # host arrays: nothing to compile
    if nc == 0 and nd == 0 and nf == 0:
        r = arx_ls(dy, du, na, nb, nkt, full_a=full_a, offset=est, ts=ts, u0=u0, y0=yref)
        return r.model, dict(engine="ls", converged=True, cost=float(r.cost), covariance=r.covariance,
                             std=r.std, start_costs=np.array([[float(r.cost)]] * ny),
                             n_steps=0, offset=offset, reference=None, start_model=None)
    if progress:
        progress(f"ARX start (na={max(n_den, 1)}, nb={nb}, offset={offset})")
    start = arx_ls(dy, du, max(n_den, 1), nb, nkt, full_a=arx_full, offset=est, u0=u0,
                   y0=yref).model
    m = ny if arx_full and ny > 1 else 1
    L = max(max(r) for r in nkt) + max(nb, 1) - 1
    spec = PolySpec(m=m, na=na, nb=nb, nc=nc, nd=nd, nf=nf, nu=nu, L=L, offset=est,
                 common_f=bool(common_f) and nf > 0)
    a_arx = np.asarray(start.a)                                       # (ny, m', n_den)
    parts = []
    if na:
        parts.append(a_arx[:, :, :na].reshape(ny, -1) if nf == 0 else np.zeros((ny, m * na)))
    parts.append(np.asarray(start.b).reshape(ny, -1))
    parts.append(np.zeros((ny, nc)))
    parts.append(np.zeros((ny, nd)))
    if nf:
        own = a_arx[:, 0, :nf] if a_arx.shape[1] == 1 else a_arx[np.arange(ny), np.arange(ny), :nf]
        rho = _atanh_reflection(own)                                     # (ny, nf)
        parts.append(rho if spec.common_f else np.repeat(rho[:, None, :], nu, axis=1).reshape(ny, -1))
    if est:
        dy0 = np.asarray(start.y0) - yref
        if na and nf == 0:      # kappa = A(1) (y0 - yref) for the A kept from ARX
            parts.append((_a_at_one(a_arx[:, :, :na]) @ dy0)[:, None])
        else:
            parts.append(dy0[:, None])
    theta0 = np.concatenate(parts, axis=1)
    starts = perturb_starts(theta0, n_starts, seed, draws=engine)      # (ny, K, p)
    dt = y.dtype
    if progress:
        progress(f"PEM: {ny} output rows x {starts.shape[1]} starts, {spec.n_params} parameters each")
    if engine == "numpy":
        res = minimize_rows(starts, dy, du, nkt, spec, max_steps=max_steps,
                            screen_steps=screen_steps, covariance=covariance)
    else:
        res = _minimize_compiled(starts, dy, du, nkt, spec, shape_orders, dt, solver=solver,
                                 max_steps=max_steps, rtol=rtol, atol=atol,
                                 covariance=covariance, screen_steps=screen_steps, batch=batch)
    if covariance and m == 1 and solver in ("lm", "gn") and extend_rounds > 0:
        res = extend_rows(res, dy, du, nkt, spec, max_steps=max_steps, rounds=extend_rounds)
    cost = np.asarray(res.cost)
    if not np.all(np.isfinite(cost)):
        bad = int(np.argmax(~np.isfinite(cost)))
        raise FitError(f"fit: output {bad + 1}: no start point gave a finite prediction error")
    model = _model_from_theta(np.asarray(res.theta), spec, nkt, ts, u0, yref, dt)
    cov = std = None
    if covariance:
        cov, std = _coefficient_covariance(res.theta, res.covariance, spec)
    return model, dict(engine=engine, converged=bool(np.all(np.asarray(res.converged))),
                       cost=float(np.mean(cost)),
                       covariance=cov, std=std, start_costs=np.asarray(res.start_costs),
                       n_steps=np.asarray(res.n_steps), start_steps=np.asarray(res.start_steps),
                       row_converged=np.asarray(res.converged),
                       expected_improvement=np.asarray(res.expected_improvement),
                       offset=offset, reference=start,
                       start_model=_model_from_theta(theta0, spec, nkt, ts, u0, yref, dt))


def choose_engine(ny: int, p: int, T: int, *, noise_model: bool = False, full_a: bool = False,
                  solver: str = "lm", batch: str = "map", cores: int | None = None) -> str:
    """The PEM engine `fit_polynomial(engine="auto")` runs: `"numpy"` when its work
    $w = n_y\\,T\\,p$ ($n_y$ output rows of $p$ parameters, $T$ samples) is at most
    `AUTO_NUMPY_MAX_WORK` (`AUTO_NUMPY_MAX_WORK_NOISE` for rows with a noise model, `nc` or
    `nd`), or when only one core is free (`cores`, default the process's CPU affinity), else
    `"jax"`; always `"jax"` for what only the compiled engine solves (a full A, `solver` other
    than `"lm"`, `batch="vmap"`).

    The NumPy engine compiles nothing and runs on one core, its cost growing with $w$; the
    compiled one pays its compilation once per process and shape, then runs on every core. The
    thresholds are where they were measured to cross, cold in fresh processes on W1 records
    (`benchmarks/polynomial_engine_crossover.py`).
    """
    if full_a or solver != "lm" or batch != "map":
        return "jax"
    if cores is None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    limit = AUTO_NUMPY_MAX_WORK_NOISE if noise_model else AUTO_NUMPY_MAX_WORK
    return "numpy" if (cores or 1) < 2 or ny * p * T <= limit else "jax"


def _minimize_compiled(starts, dy, du, nkt, spec: PolySpec, shape_orders, dt, **kw):
    """`pem.minimize_many` of every output row (`fit_polynomial`'s `engine="jax"`); with
    `shape_orders`, in the compiled shape of that larger structure (missing coefficients
    masked), the result mapped back to `spec`'s own parameters."""
    ny = dy.shape[1]
    big = spec if shape_orders is None else padded_spec(spec, shape_orders, nkt)
    args = poly_args(dy, du, big, nkt, spec.m > 1)
    idx = parameter_embedding(spec, big)
    if shape_orders is not None:    # the shared compiled shape, missing coefficients masked
        padded = np.zeros(starts.shape[:2] + (big.n_params,))
        padded[..., idx] = starts
        starts = padded
        mask = np.zeros((ny, big.n_params))
        mask[:, idx] = 1.0
        args = args + (placed(mask, dt),)
    res = minimize_many(poly_residual, placed(starts, dt), args, throw=False, **kw)
    if shape_orders is not None:
        # back to the structure's own parameters; the covariance's noise variance divides by
        # T - p: rescaled from the shared shape's p to the structure's own
        T = dy.shape[0]
        scale = max(T - big.n_params, 1) / max(T - spec.n_params, 1)
        cov_own = np.asarray(res.covariance)[:, idx][:, :, idx] * scale
        own = (np.asarray(res.theta)[:, idx], cov_own, np.asarray(res.std)[:, idx] * np.sqrt(scale))
        res = eqx.tree_at(lambda r: (r.theta, r.covariance, r.std), res, own)
    return res


def padded_spec(spec: PolySpec, orders: dict, nkt) -> PolySpec:
    """The structure `spec` enlarged to the orders `orders` (`na`, `nb`, `nc`, `nd`, `nf`; each
    the larger of the two): a compiled shape that `spec` and smaller structures share."""
    o = {n: max(getattr(spec, n), int(orders.get(n, 0))) for n in ("na", "nb", "nc", "nd", "nf")}
    L = max(max(r) for r in nkt) + max(o["nb"], 1) - 1
    return spec._replace(**o, L=max(L, spec.L))


def parameter_embedding(s: PolySpec, big: PolySpec) -> np.ndarray:
    """Positions of the parameters of `s` in the parameter vector of the larger `big` (same
    m, nu, offset, common_f): each coefficient block `(rows, n)` sits in the first `n`
    columns of `big`'s `(rows, n_big)` block."""
    def block(rows, n, n_big, start):
        return start + (np.arange(rows)[:, None] * n_big + np.arange(n)[None, :]).ravel()

    f_rows = 1 if s.common_f else s.nu
    starts = np.cumsum([0, big.m * big.na, big.nu * big.nb, big.nc, big.nd])
    idx = [block(s.m, s.na, big.na, starts[0]), block(s.nu, s.nb, big.nb, starts[1]),
           block(1, s.nc, big.nc, starts[2]), block(1, s.nd, big.nd, starts[3]),
           block(f_rows, s.nf, big.nf, starts[4])]
    if s.offset:
        idx.append(np.array([big.n_coef]))
    return np.concatenate(idx).astype(int)


def _coefficient_covariance(theta, cov_theta, spec: PolySpec):
    """Covariance and standard deviations of the model coefficients `[a, b, c, d, f]` per
    output row, $J \\Sigma_\\theta J^\\top$ with $J$ the Jacobian of the coefficients in the
    parameters (`pem_numpy.coefficient_jacobian`; NumPy: nothing to compile)."""
    Jt = np.stack([coefficient_jacobian(th, spec) for th in np.asarray(theta, np.float64)])
    cov = np.einsum("iab,ibc,idc->iad", Jt, np.asarray(cov_theta, np.float64), Jt)
    return cov, np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None))


def _a_at_one(a: np.ndarray) -> np.ndarray:
    """$A(1) = I + \\sum_k A_k$ of the A coefficients `a (ny, m, na)` (diagonal when m = 1)."""
    ny = a.shape[0]
    s = a.sum(axis=2)
    return np.eye(ny) + (np.diag(s[:, 0]) if a.shape[1] == 1 and ny > 1 else s)


def _model_from_theta(theta, spec: PolySpec, nkt, ts: float, u0, yref, dtype) -> Polynomial:
    """The `Polynomial` of per-output parameter vectors `theta (ny, p)` (`_unpack` of every
    row, in NumPy: nothing to compile)."""
    theta = np.asarray(theta, np.float64)
    ny, s = theta.shape[0], spec
    k = np.cumsum([0, s.m * s.na, s.nu * s.nb, s.nc, s.nd, s.n_f])
    a = theta[:, k[0]:k[1]].reshape(ny, s.m, s.na)
    b = theta[:, k[1]:k[2]].reshape(ny, s.nu, s.nb)
    c = step_up(np.tanh(theta[:, k[2]:k[3]]))
    d = step_up(np.tanh(theta[:, k[3]:k[4]]))
    rho_f = theta[:, k[4]:k[5]].reshape(ny, 1 if s.common_f else s.nu, s.nf)
    f = step_up(np.tanh(np.broadcast_to(rho_f, (ny, s.nu, s.nf))))
    y0 = np.asarray(yref, np.float64)
    if s.offset:
        y0 = y0 + np.linalg.solve(_a_at_one(a), theta[:, s.n_coef])
    as_dt = lambda x: placed(x, dtype)  # noqa: E731
    return Polynomial(a=as_dt(a), b=as_dt(b), c=as_dt(c), d=as_dt(d), f=as_dt(f), nk=nkt, ts=ts,
                      u0=as_dt(u0), y0=as_dt(y0))


def polynomial_orders(family: str, o: dict) -> dict:
    """All six orders `fit_polynomial` takes (`na`, `nb`, `nc`, `nd`, `nf`, `nk`) from a
    family's orders `o` in MATLAB's naming (the others 0, `nk` 1)."""
    full = {"na": 0, "nb": 0, "nc": 0, "nd": 0, "nf": 0, "nk": 1}
    full.update(o)
    return full


def n_params_per_output(family: str, o: dict, nu: int, ny: int = 1, full_a: bool = False) -> int:
    """Number of parameters of one output row of a polynomial model."""
    k = polynomial_orders(family, o)
    m = ny if full_a else 1
    return m * k["na"] + nu * k["nb"] + k["nc"] + k["nd"] + nu * k["nf"]


@register_fitter(POLYNOMIAL_FAMILIES, options=fit_polynomial)
def fit_polynomial_family(data: IOData, family: str, orders: dict, *, seed: int = 0,
                          n_starts: int = 8, progress: Callable | None = None,
                          **kw) -> FitResult:
    """`fit`'s fitter of the polynomial families: `fit_polynomial` of `data` with the family's
    `orders` (MATLAB's naming, e.g. `{"na": 2, "nb": 2, "nk": 1}`) and options `kw`.

    **Returns:** a `FitResult` (`seconds` left to `fit`, which times the whole call).
    """
    full_a = bool(kw.get("full_a", False))
    pk = polynomial_orders(family, orders)
    n0 = max(pk["na"], pk["nk"] + max(pk["nb"], 1) - 1)     # rows lost to the regressors
    require_samples(data, n_params_per_output(family, orders, data.n_inputs, data.n_outputs,
                                              full_a) + n0 + 1, what=f"{family} model")
    model, info = fit_polynomial(data.y, data.u, ts=data.ts, seed=seed, n_starts=n_starts,
                                 progress=progress, **pk, **kw)
    model, check, repaired = guard_polynomial(model, info, data, family, orders)
    extra = {"engine": info["engine"], "start_costs": info["start_costs"], "n_steps": info["n_steps"],
             "offset": info["offset"], "check": check.to_dict()}
    if "row_converged" in info:     # PEM: per output row, and what its GN step would still gain
        extra["row_converged"] = [bool(c) for c in info["row_converged"]]
        extra["expected_improvement"] = [float(g) for g in info["expected_improvement"]]
    if repaired:
        extra["repaired"] = repaired
    return FitResult(model=model, family=family, orders=orders,
                     converged=bool(info["converged"] and check.ok and not repaired),
                     cost=info["cost"], covariance=None if repaired else info["covariance"],
                     std=None if repaired else info["std"], extra=extra)


def guard_polynomial(model: Polynomial, info: dict, data: IOData, family: str, orders: dict):
    """`guard.check_model` of a fitted polynomial model against its ARX reference; a model
    that fails is replaced by the PEM's start point (the ARX-based estimate in the family's
    structure) when that one passes, otherwise the fit fails.

    **Returns:** `(model, check, repaired)`: `repaired` says what was replaced ('' if nothing).

    **Raises:** `FitError` (one line) when neither the fitted model nor its start passes.
    """
    check = check_model(model, data, info.get("reference"))
    if check.ok:
        return model, check, ""
    start = info.get("start_model")
    if start is not None:
        c0 = check_model(start, data, info.get("reference"))
        if c0.ok:
            return start, c0, (f"PEM result rejected ({check.reason()}); the ARX-based start "
                               f"point is returned instead")
    orders_txt = ", ".join(f"{k} {v}" for k, v in orders.items())
    raise FitError(f"fit: {family} [{orders_txt}]: {check.reason()}; no stable model found "
                   f"(try other orders)")


__all__ = ["AUTO_NUMPY_MAX_WORK", "AUTO_NUMPY_MAX_WORK_NOISE", "ENGINES", "POLYNOMIAL_FAMILIES", "PolySpec", "choose_engine", "fit_polynomial", "fit_polynomial_family", "guard_polynomial",
           "n_params_per_output", "poly_args", "poly_cost", "poly_residual", "polynomial_orders"]
