"""Extra starts of the candidate fits: where a mechanism's fit from the neutral start
(`mechanisms.initial_theta`) stops at a local optimum or short of it at the iteration cap, the
candidate is also fitted from these starts, and each zone keeps its best (`best_of_starts`: the
per-zone problems are independent)."""

from __future__ import annotations

import numpy as np

from .mechanisms import TAUW_MIN, Layout, share_parameter, wall_parameters

#: effective time constants $\tau_w / (1 + \gamma)$ (s) of a stored-heat body's extra starts
#: (`body_starts`): a body slower than the neutral start's 500 s (chamber walls, 20-60 min) is
#: otherwise lost to the local optimum at the shortest time constant the model allows (set on
#: development set 6's slow bodies)
BODY_START_TAUS = (1500.0, 4000.0)


def body_starts(theta: np.ndarray, lay: Layout, taus=BODY_START_TAUS) -> list:
    """Copies of the starts `theta (..., P)` with the wall's effective time constant
    $\\tau_w / (1 + \\gamma)$ at each of `taus` (s), $\\gamma$ left at its start."""
    th = np.asarray(theta, float)
    _, gam = wall_parameters(th[..., lay.sl("log_tauw")], th[..., lay.sl("log_gamma")])
    out = []
    for tau in taus:
        t = th.copy()
        t[..., lay.sl("log_tauw")] = np.log(np.maximum(tau * (1.0 + gam) - TAUW_MIN, 1.0))
        out.append(t)
    return out


#: shares ρ of the tangent loss at which radiation's extra fits start (`rad_starts`): from the neutral
#: 0.5 a steep loss (ρ > 1, convection) is reached slowly, and a fit stopped at the iteration cap
#: misjudges the mechanism (a steep loss is read as too shallow at the cap)
RAD_SHARE_STARTS = (1.5, 3.0)


def rad_starts(theta: np.ndarray, lay: Layout, shares=None) -> list:
    """Copies of the starts `theta (..., P)` with the radiative share at each of `shares`
    (default `RAD_SHARE_STARTS`; every share in (0, `RAD_SHARE_MAX`))."""
    shares = RAD_SHARE_STARTS if shares is None else shares
    return [np.where(lay.mask(("rad_share",)) > 0, share_parameter(s), np.asarray(theta, float))
            for s in shares]


def best_of_starts(theta: np.ndarray, resid: np.ndarray, k: int, extra) -> tuple:
    """Candidate fits `theta (S, n, P)` and estimation residuals `resid (S, T, n)` with each
    zone's fit of candidate `k` replaced by the one of the fits `extra` (indices of other
    starts of the same candidate) with the smallest sum of squared residuals; the extra fits
    are dropped (the zones' problems are independent, so each keeps its own best start)."""
    idx = [k] + list(extra)
    sse = np.stack([np.sum(np.asarray(resid[j]) ** 2, axis=0) for j in idx])    # (starts, n)
    best = np.argmin(np.where(np.isfinite(sse), sse, np.inf), axis=0)
    th, rs = np.array(theta), np.array(resid)
    for i, b in enumerate(best):
        th[k, i], rs[k, :, i] = theta[idx[b], i], resid[idx[b], :, i]
    keep = [j for j in range(th.shape[0]) if j not in set(extra)]
    return th[keep], rs[keep]


__all__ = ["BODY_START_TAUS", "RAD_SHARE_STARTS", "best_of_starts", "body_starts", "rad_starts"]
