"""Order selection (AIC / BIC / FPE over a grid) and input-delay estimation from an FIR fit.

Criteria on the estimation data (Ljung 1999, §16.4), with $N$ samples, $p$ parameters in all
and $V = \\det\\big(\\frac1N \\sum_t \\varepsilon(t)\\varepsilon(t)^\\top\\big)$ from the one-step
prediction errors:

$$\\mathrm{AIC} = N \\log V + 2p, \\qquad \\mathrm{BIC} = N\\log V + p\\log N, \\qquad
  \\mathrm{FPE} = V\\,\\frac{1 + p/N}{1 - p/N}.$$

Delays: an impulse response $g_{ij}(k)$, $k = 0..M$, fitted by least squares (with a few
own-output lags to whiten slow dynamics), and its $\\pm 3\\sigma$ band; the delay of pair
$(i, j)$ is the first lag whose coefficient leaves the band (Ljung 1999, §13.7).
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import Callable

import jax.numpy as jnp
import numpy as np

from ..data import IOData, require_excitation
from ..errors import ConfigError, DataError, FitError, ModelError
from ..families import ORDER_NAMES
from .arx import arx_ls
from .polynomial import fit_polynomial, n_params_per_output, polynomial_orders

CRITERIA = ("aic", "bic", "fpe")

#: default candidate grids (MATLAB order names); bj ties nc = nd to keep the grid small
DEFAULT_GRIDS = {
    "arx": {"na": (1, 2, 3), "nb": (1, 2, 3)},
    "armax": {"na": (1, 2), "nb": (1, 2), "nc": (1, 2)},
    "oe": {"nb": (1, 2), "nf": (1, 2)},
    "bj": {"nb": (1, 2), "nc": (1, 2), "nf": (1, 2)},
}


@dataclasses.dataclass(frozen=True)
class DelayEstimate:
    """Per input/output pair delays from an FIR fit.

    **Fields:** `nk` `(ny, nu)` delay in samples (-1 where no coefficient is significant),
    `coef` and `std` `(ny, nu, M+1)` the impulse-response coefficients and their standard
    deviations, `common` the most frequent delay over the significant pairs (1 if none).
    """

    nk: np.ndarray
    coef: np.ndarray
    std: np.ndarray
    common: int


def information_criterion(residuals, n_params: int, criterion: str = "aic") -> float:
    """AIC, BIC or FPE of prediction errors `residuals (N, ny)` for a model with `n_params`."""
    if criterion not in CRITERIA:
        raise ConfigError(f"orders: criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    e = np.asarray(residuals, dtype=np.float64)
    N = e.shape[0]
    sign, logdet = np.linalg.slogdet(e.T @ e / N)
    if sign <= 0 or not np.isfinite(logdet):
        return float("inf")
    if criterion == "aic":
        return float(N * logdet + 2 * n_params)
    if criterion == "bic":
        return float(N * logdet + n_params * np.log(N))
    if n_params >= N:
        return float("inf")
    return float(np.exp(logdet) * (1 + n_params / N) / (1 - n_params / N))


def estimate_delays(data: IOData, max_lag: int = 10, *, n_ar: int = 2,
                    n_sigma: float = 3.0) -> DelayEstimate:
    """Input delays per pair from a least-squares impulse response with a $\\pm n_\\sigma$ band.

    Fits $y_i(t) = -\\sum_{k=1}^{n_{ar}} a_k y_i(t-k) + \\sum_j \\sum_{k=0}^{M} g_{ijk} u_j(t-k) + e$
    (`n_ar = 0`: a pure FIR) on mean-removed data; lags $k < n_k$ have $g_{ijk} = 0$ exactly, and
    the first lag with $|g_{ijk}| > n_\\sigma \\sigma_{ijk}$ is the delay.
    """
    if max_lag < 1 or n_ar < 0:
        raise ConfigError(f"estimate_delays: need max_lag >= 1 and n_ar >= 0, got {max_lag}, {n_ar}")
    y = jnp.asarray(data.y - data.y.mean(axis=0))
    u = jnp.asarray(data.u - data.u.mean(axis=0))
    ny, nu = y.shape[1], u.shape[1]
    nb = max_lag + 1
    if data.n_samples <= n_ar + nu * nb + max(n_ar, max_lag) + 1:
        raise DataError(f"estimate_delays: {data.n_samples} samples are too few for an FIR of "
                        f"{nb} lags on {nu} inputs")
    r = arx_ls(y, u, n_ar, nb, 0)
    coef = np.asarray(r.model.b)                                        # (ny, nu, nb)
    std = np.asarray(r.std)[:, n_ar:].reshape(ny, nu, nb)
    sig = np.abs(coef) > n_sigma * std
    nk = np.where(sig.any(axis=2), np.argmax(sig, axis=2), -1)
    found = nk[nk >= 0]
    common = int(np.bincount(found).argmax()) if found.size else 1
    return DelayEstimate(nk=nk, coef=coef, std=std, common=common)


def _grid(family: str, grid: dict | None):
    g = dict(DEFAULT_GRIDS[family]) if grid is None else dict(grid)
    names = {"arx": ("na", "nb"), "armax": ("na", "nb", "nc"), "oe": ("nb", "nf"),
             "bj": ("nb", "nc", "nf")}[family]
    for n in names:
        if n not in g:
            raise ConfigError(f"select_orders: grid for {family} needs `{n}`")
        vals = tuple(g[n])
        if not vals or any(int(v) != v or v < 0 for v in vals):
            raise ModelError(f"select_orders: grid values for {n} must be integers >= 0")
    for combo in itertools.product(*(tuple(int(v) for v in g[n]) for n in names)):
        o = dict(zip(names, combo))
        if family == "bj":
            o["nd"] = o["nc"] if "nd" not in g else o.get("nd", o["nc"])
        yield o


def select_orders(data: IOData, family: str, *, criterion: str = "aic", grid: dict | None = None,
                  nk: int | None = None, full_a: bool = False, seed: int = 0, n_starts: int = 1,
                  max_steps: int = 60, progress: Callable | None = None):
    """Choose polynomial orders over a grid by AIC, BIC or FPE on the estimation data.

    **Arguments:**
    - `family`: `arx`, `armax`, `oe` or `bj`.
    - `grid`: `{name: candidates}` (defaults: `DEFAULT_GRIDS`; for `bj`, `nd = nc`).
    - `nk`: the input delay; `None` estimates it (`estimate_delays(...).common`).
    - ARMAX/OE/BJ candidates are fitted by PEM with `n_starts` starts and `max_steps` steps.

    **Returns:** `(orders, table)`: the chosen orders in MATLAB's naming (with `nk`) and one dict
    per candidate with its orders, parameter count, criterion value and `chosen` flag.
    """
    if family not in DEFAULT_GRIDS:
        raise ModelError(f"select_orders: no order grid for family {family!r}")
    if criterion not in CRITERIA:
        raise ConfigError(f"select_orders: criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    require_excitation(data)
    if nk is None:
        nk = estimate_delays(data, max_lag=min(10, max(1, data.n_samples // 20))).common
    table = []
    best = None
    for o in _grid(family, grid):
        o = {**o, "nk": int(nk)}
        o = {n: o[n] for n in ORDER_NAMES[family]}
        p_row = n_params_per_output(family, o, data.n_inputs, data.n_outputs, full_a)
        if p_row == 0 or data.n_samples <= p_row + 10:
            continue
        if progress:
            progress(f"order candidate {o}")
        try:
            model, _ = fit_polynomial(data.y, data.u, ts=data.ts, seed=seed, n_starts=n_starts,
                                      max_steps=max_steps, covariance=False, full_a=full_a,
                                      **polynomial_orders(family, o))
        except FitError:
            continue
        eps = model.residuals(jnp.asarray(data.y), jnp.asarray(data.u))
        p = p_row * data.n_outputs
        value = information_criterion(eps, p, criterion)
        row = {**o, "n_params": p, criterion: value, "chosen": False}
        table.append(row)
        if np.isfinite(value) and (best is None or value < best[0]):
            best = (value, len(table) - 1)
    if best is None:
        raise FitError(f"select_orders: no {family} candidate could be fitted")
    table[best[1]]["chosen"] = True
    chosen = {n: table[best[1]][n] for n in ORDER_NAMES[family]}
    return chosen, table


__all__ = ["select_orders", "estimate_delays", "information_criterion", "DelayEstimate",
           "CRITERIA", "DEFAULT_GRIDS"]
