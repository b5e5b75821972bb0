"""Operating points: the levels a record's deviations are taken from.

Every estimator fits deviations $\\tilde y = y - y_0$, $\\tilde u = u - u_0$ from an operating
point stored in the model (`u0`, `y0`), so that `model.simulate(u)` is in absolute units. The
record is taken to start

- at rest at the data's mean operating point (`"mean"`: $u_0$, $y_0$ the means), or
- at rest with zero input (`"rest"`: a cold machine, heaters off; $u_0 = 0$ and $y_0$ the
  output level at rest, known (`known_rest_level`) or estimated from the first samples
  (`rest_window`, `estimate_rest_level`)), or
- for polynomial models also at rest with zero input with $y_0$ estimated with the other
  parameters (`"estimate"`).

`OPERATING_POINTS` are the modes of the state-space estimators (`n4sid`, `fit_statespace`),
`OFFSETS` those of the polynomial fit (`fit_polynomial`, with `"auto"`: `offset_mode`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..models import polynomial_numpy
from ..models.polynomial import Polynomial
from .arx import arx_ls

#: operating-point modes of the state-space estimators (`n4sid`, `fit_statespace`)
OPERATING_POINTS = ("mean", "rest")
#: operating-point modes of the polynomial fit (`fit_polynomial`'s `offset`)
OFFSETS = ("auto", "mean", "rest", "estimate")
#: extra ARX orders of the model whose response `estimate_rest_level` removes
REST_ARX_EXTRA = 3


def rest_window(T: int) -> int:
    """Samples M at the start of a record from which its level at rest is estimated: 1 % of
    them, 1 to 100."""
    return int(min(max(T // 100, 1), 100))


def known_rest_level(level, ny: int) -> np.ndarray:
    """A user-given output level at rest (a measured ambient temperature; 0 for data in °C
    above ambient) as a `(ny,)` array; a number applies to every output."""
    try:
        arr = np.asarray(level, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"rest_level must be a number or one number per output, "
                          f"got {level!r}") from None
    if arr.ndim > 1 or (arr.ndim == 1 and arr.shape[0] != ny):
        raise ConfigError(f"rest_level must be a number or {ny} numbers (one per output), "
                          f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError("rest_level must be finite")
    return np.broadcast_to(arr, (ny,)).copy()


def estimate_rest_level(y, u, nb, nkt, n_den, full_a, ts):
    """Output level of a record that starts at rest with zero input.

    The first sample alone carries its full measurement noise (on W1 that costs 0.1–0.2
    points of validation fit, `experiments/identification_level_check.py`). Instead the first
    M = 1 % of the samples (1 to 100) are averaged after removing the response an ARX model
    simulates for them from rest: $\\hat y_0 = \\frac{1}{M}\\sum_{t<M}\\big(y(t) -
    \\hat y_{\\mathrm{dev}}(t)\\big)$. The ARX orders are the family's plus `REST_ARX_EXTRA`:
    an ARX model of the family's own orders is biased on output-error data, and its biased
    response moved the level by −0.12 to −0.18 °C on OE data and by −0.19 °C on W1 with 16
    zones (`experiments/rest_level_check.py`; the 3σ coverage of the OE parameters fell to 0.91
    in `tests/identify/test_fit_coverage.py`'s slow study); a higher-order ARX approximates any
    linear system better.
    """
    yn, un = np.asarray(y, np.float64), np.asarray(u, np.float64)
    M = rest_window(yn.shape[0])
    if M == 1:
        return y[0]
    m = arx_ls(yn - yn[0], un, max(n_den, 1) + REST_ARX_EXTRA, nb + REST_ARX_EXTRA, nkt,
               full_a=full_a, ts=ts, u0=np.zeros(un.shape[1]), y0=yn[0]).model
    level = np.mean(yn[:M] - (_simulate_np(m, un[:M]) - yn[0]), axis=0)
    return jnp.asarray(level if np.all(np.isfinite(level)) else yn[0], y.dtype)


def _simulate_np(model: Polynomial, u: np.ndarray) -> np.ndarray:
    """`model.simulate(u)` as a NumPy array: NumPy filters where they apply (no compile)."""
    if polynomial_numpy.supported(model):
        return polynomial_numpy.simulate(model, u)
    return np.asarray(_simulate(model, jnp.asarray(u)))


def operating_point(mode: str, y, u, rest_level=None):
    """`(y0, u0, estimate_constant)` of an operating-point mode of `OFFSETS` other than
    `"auto"` (see `fit_polynomial`); `rest_level` is the output level at rest of `"rest"`
    (None: the first sample)."""
    y, u = np.asarray(y), np.asarray(u)       # host arrays: nothing to compile
    if mode == "mean":
        return np.mean(y, axis=0), np.mean(u, axis=0), False
    y0 = np.asarray(rest_level) if (mode == "rest" and rest_level is not None) else y[0]
    return y0, np.zeros(u.shape[1], u.dtype), mode == "estimate"


@eqx.filter_jit
def _simulate(model: Polynomial, u):
    return model.simulate(u)


def offset_mode(y, u, nb, nkt, n_den, full_a, ts, rest_level=None):
    """The operating-point mode whose ARX(n_den, nb) simulates the estimation data best.

    The modes differ in the state the record is assumed to start from: at rest at the data's
    mean operating point, or at rest with zero input (a cold machine, heaters off) at the first
    sample's temperature, that temperature either fixed or estimated with the rest.
    """
    y, u = np.asarray(y), np.asarray(u)
    errs = {}
    for mode in OFFSETS[1:]:
        yref, u0, est = operating_point(mode, y, u, rest_level)
        m = arx_ls(y - yref, u - u0, max(n_den, 1), nb, nkt, full_a=full_a,
                   offset=est, ts=ts, u0=u0, y0=yref).model
        errs[mode] = float(np.mean((y - _simulate_np(m, u)) ** 2))
    ok = {k: v for k, v in errs.items() if np.isfinite(v)}
    return min(ok, key=ok.get) if ok else "mean"


__all__ = ["OFFSETS", "OPERATING_POINTS", "REST_ARX_EXTRA", "estimate_rest_level",
           "known_rest_level", "offset_mode", "operating_point", "rest_window"]
