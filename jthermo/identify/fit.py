"""`fit()`: one entry point for every model family.

Orders follow MATLAB's System Identification Toolbox: arx `(na, nb, nk)`, armax
`(na, nb, nc, nk)`, oe `(nb, nf, nk)`, bj `(nb, nc, nd, nf, nk)`, ss `(n,)`, greybox `()`.

`fit` checks the request, chooses polynomial orders over a grid when none are given
(`orders.select_orders`) and hands the data to the family's fitter (`result.FITTERS`):
`polynomial.fit_polynomial` (arx, armax, oe, bj), `statespace.fit_statespace` (ss) or
`greybox.fit_greybox` (greybox).
"""

from __future__ import annotations

import dataclasses
import inspect
import time
import warnings
from typing import Callable

import numpy as np

from .. import runtime
from ..data import IOData, require_excitation, require_output_variation
from ..errors import ConfigError, DataError, ModelError
from ..models import polynomial_numpy
from ..models.envelope import Envelope

# the fitters register themselves in `FITTERS` when their modules load
from . import heat
from .greybox import fit_greybox
from .orders import CRITERIA, DEFAULT_GRIDS, select_orders
from .polynomial import (
    fit_polynomial, n_params_per_output, poly_cost, poly_residual, polynomial_orders,
)
from .screening import screen_orders
from .result import FAMILIES, FITTERS, ORDER_NAMES, FitResult
from .statespace import fit_statespace


def _check_orders(family: str, orders) -> dict[str, int]:
    names = ORDER_NAMES[family]
    if isinstance(orders, (int, np.integer)) and not isinstance(orders, bool):
        orders = (int(orders),)
    try:
        vals = tuple(orders)
    except TypeError:
        raise ModelError(f"fit: orders for {family} must be a tuple {names}, got {orders!r}") from None
    if len(vals) != len(names):
        raise ModelError(f"fit: {family} takes {len(names)} orders ({','.join(names) or 'none'}), "
                         f"got {len(vals)}")
    out = {}
    for n, v in zip(names, vals):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ModelError(f"fit: order {n} must be an integer >= 0, got {v!r}")
        out[n] = int(v)
    if family == "arx" and out["na"] == 0 and out["nb"] == 0:
        raise ModelError("fit: arx with na = nb = 0 has no parameters")
    if family in ("armax", "oe", "bj") and out["nb"] == 0:
        raise ModelError(f"fit: {family} needs nb >= 1")
    if family == "ss" and out["n"] < 1:
        raise ModelError("fit: state order n must be >= 1")
    return out


def fit(data: IOData, family: str, orders: tuple[int, ...] | None = None, *, seed: int = 0,
        n_starts: int = 8, criterion: str = "aic", progress: Callable | None = None,
        physics: str = "heat", **kw) -> FitResult:
    """Fit a model of `family` to estimation data.

    **Arguments:**
    - `data`: estimation `IOData` (absolute units).
    - `family`: one of `arx`, `armax`, `oe`, `bj`, `ss`, `greybox`.
    - `orders`: MATLAB's order tuple for the family (see module docstring); `None` chooses the
      orders over a grid by `criterion` (and the delay from an FIR estimate).
    - `seed`, `n_starts`: multi-start (start points solved together with `vmap`).
    - `criterion`: `aic`, `bic` or `fpe` for automatic orders.
    - `progress`: optional callable receiving one-line status strings.
    - `physics`: `"heat"` (the default: inputs are heat commands, outputs temperatures; the
      model is fitted as heat behaves, `identify.heat`: logged set points and constant inputs
      left out, `extra["physics"]` the selection path and verdict) or `"none"` (any linear
      system, every column as given).
    - `**kw`: passed on (`full_a`, `solver`, `max_steps`, `covariance`, `offset`,
      `rest_level`, `common_f`, ... for polynomial families, see `fit_polynomial`; whatever
      `fit_statespace` / `fit_greybox` accept otherwise); an unknown option is a `ConfigError`.

    **Returns:** a `FitResult`.
    """
    runtime.guard()     # a long-lived process stays below the memory-map bound
    t0 = time.perf_counter()
    if not isinstance(family, str) or family.lower() not in FAMILIES:
        raise ModelError(f"fit: unknown model family {family!r} (expected one of {', '.join(FAMILIES)})")
    family = family.lower()
    if criterion not in CRITERIA:
        raise ConfigError(f"fit: criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    if isinstance(n_starts, bool) or not isinstance(n_starts, (int, np.integer)) or n_starts < 1:
        raise ConfigError(f"fit: n_starts must be an integer >= 1, got {n_starts!r}")
    if not isinstance(data, IOData):
        raise DataError(f"fit: expected IOData, got {type(data).__name__}")
    if physics not in heat.PHYSICS:
        raise ConfigError(f"fit: physics must be one of {', '.join(heat.PHYSICS)}, got {physics!r}")
    o = _check_orders(family, orders) if orders is not None else None
    if physics == "heat":
        data, dropped = heat.heat_data(data)
    require_excitation(data)
    require_output_variation(data)
    fitter = FITTERS[family]
    _check_options(fitter.options, kw, family)
    table = None
    if physics == "heat":
        res, path, table = _fit_heat(data, family, fitter, o, criterion, seed=seed,
                                     n_starts=n_starts, progress=progress, **kw)
        res = heat.with_report(res, data, path, dropped)
        return dataclasses.replace(_complete(res, family, table, t0),
                                   envelope=Envelope.from_data(data))
    if o is None and family in DEFAULT_GRIDS and not kw.get("full_a", False):
        if progress:
            progress(f"screening {family} orders by {criterion}")
        candidates, table = screen_orders(data, family, criterion=criterion)
        res = _confirm(data, family, fitter, candidates, table, criterion, seed=seed,
                       n_starts=n_starts, progress=progress, **kw)
    else:
        if o is None and family in DEFAULT_GRIDS:     # a full A: the PEM grid
            o, table = select_orders(data, family, criterion=criterion, full_a=True, seed=seed,
                                     n_starts=1)
        res = fitter.run(data, family, o, seed=seed, n_starts=n_starts, progress=progress, **kw)
    return dataclasses.replace(_complete(res, family, table, t0),
                               envelope=Envelope.from_data(data))


def _fit_heat(data: IOData, family: str, fitter, o: dict | None, criterion: str, *, seed: int,
              n_starts: int, progress, **kw):
    """`(result, path, table)` of the heat path (`identify.heat`)."""
    if family == "ss":
        res, path = heat.fit_ss_heat(data, o, criterion, fitter, seed=seed, n_starts=n_starts,
                                     progress=progress, **kw)
        return res, path, None
    if family == "greybox":
        res, path = heat.fit_greybox_heat(data, fitter, seed=seed, n_starts=n_starts,
                                          progress=progress, **kw)
        return res, path, None
    if o is not None or kw.get("full_a", False):
        table = None
        if o is None:       # a full A: the PEM grid
            o, table = select_orders(data, family, criterion=criterion, full_a=True, seed=seed,
                                     n_starts=1)
        res = fitter.run(data, family, o, seed=seed, n_starts=n_starts, progress=progress, **kw)
        chk = heat.heat_check(res.model, data)
        name = f"{family} {','.join(f'{k}={v}' for k, v in o.items())}"
        if not chk["shape_ok"]:
            raise ModelError(f"fit: {name} is not a plant heat could be ({chk['warnings'][0]}); "
                             "leave the orders to the automatic choice, or physics='none'")
        if not chk["plausible"]:    # a heated body whose steady states miss part of the record
            warnings.warn(f"fit: {name}: {chk['warnings'][0]}; kept because the orders were given",
                          stacklevel=3)
            return res, [f"{name}: kept as given; {'; '.join(chk['warnings'])}"], table
        return res, [f"{name}: plausible"], table

    def screen(d, fam):
        if progress:
            progress(f"screening {fam} orders by {criterion}")
        return screen_orders(d, fam, criterion=criterion)

    return heat.fit_polynomial_heat(data, family, fitter, screen, criterion, seed=seed,
                                    n_starts=n_starts, progress=progress, **kw)


def _confirm(data: IOData, family: str, fitter, candidates: list[dict], table: list[dict],
             criterion: str, **kw) -> FitResult:
    """PEM fits of the screened `candidates` (the chosen orders, and a close runner-up);
    with two, the one whose one-step prediction errors score better by `criterion` wins.
    A candidate that fails (`FitError`) is skipped while another remains."""
    from ..errors import FitError
    from .orders import information_criterion

    results, failures = [], []
    if len(candidates) > 1 and family != "arx":     # one compiled PEM shape for all of them
        full = [polynomial_orders(family, o) for o in candidates]
        kw = {**kw, "shape_orders": {n: max(f[n] for f in full)
                                     for n in ("na", "nb", "nc", "nd", "nf")}}
    for o in candidates:
        try:
            r = fitter.run(data, family, o, **kw)
        except FitError as exc:
            failures.append(exc)
            continue
        eps = polynomial_numpy.residuals(r.model, data.y, data.u) if \
            polynomial_numpy.supported(r.model) else r.model.residuals(data.y, data.u)
        p = n_params_per_output(family, o, data.n_inputs, data.n_outputs) * data.n_outputs
        value = information_criterion(eps, p, criterion)
        table.append({**o, "stage": "pem", "n_params": p, criterion: value, "chosen": False})
        results.append((value if np.isfinite(value) else np.inf, len(table) - 1, r))
    if not results:
        raise failures[0]
    value, row, best = min(results, key=lambda t: t[0])
    table[row]["chosen"] = True
    return best


#: arguments of the family fitters that `fit` sets itself (from the data, orders, seed, ...)
_SET_BY_FIT = {"data", "n", "y", "u", "na", "nb", "nc", "nd", "nf", "nk", "ts", "seed", "n_starts",
               "progress"}


def _check_options(fitter: Callable, kw: dict, family: str) -> None:
    """A one-line error for an option the family's fitter does not take (not a TypeError)."""
    known = set(inspect.signature(fitter).parameters) - _SET_BY_FIT
    unknown = sorted(set(kw) - known)
    if unknown:
        raise ConfigError(f"fit: unknown option `{unknown[0]}` for family {family}")


def _complete(res: FitResult, family: str, table: list | None, t0: float) -> FitResult:
    """`res` with the family, the order table of an automatic choice and, where the fitter
    left it NaN, the wall time since `t0`."""
    changes = {}
    if not res.family:
        changes["family"] = family
    if not np.isfinite(res.seconds):
        changes["seconds"] = time.perf_counter() - t0
    if table is not None:
        changes["criterion_table"] = table
    return dataclasses.replace(res, **changes) if changes else res


__all__ = ["CRITERIA", "FAMILIES", "ORDER_NAMES", "FitResult", "fit", "fit_greybox",
           "fit_polynomial", "fit_statespace", "n_params_per_output", "poly_cost", "poly_residual"]
