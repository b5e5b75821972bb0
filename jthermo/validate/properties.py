"""Model properties: spectral estimates from data (MATLAB `spa`), Bode, poles and zeros, step
information, the relative gain array and information criteria for order selection."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from jaxtyping import Array, ArrayLike, Float

from ..data import IOData
from ..errors import DataError, ModelError
from ..models._base import AbstractModel
from .simulation import cross_covariance, is_traced

# ---------------------------------------------------------------- frequency domain


_LAG_WINDOWS = {"hamming": (0.54, 0.46), "hann": (0.5, 0.5)}


@eqx.filter_jit
def _blackman_tukey(y, u, omega, M: int, ts: float, window: str):
    y = y - jnp.mean(y, axis=0)
    u = u - jnp.mean(u, axis=0)
    Ryu = cross_covariance(y, u, M)                  # (2M+1, ny, nu)
    Ruu = cross_covariance(u, u, M)                  # (2M+1, nu, nu)
    tau = jnp.arange(-M, M + 1)
    a0, a1 = _LAG_WINDOWS[window]
    win = a0 + a1 * jnp.cos(jnp.pi * tau / M)        # raised-cosine lag window over |tau| <= M
    E = jnp.exp(-1j * jnp.outer(omega * ts, tau)) * win   # (nf, 2M+1)
    Phi_yu = jnp.einsum("ft,tij->fij", E, Ryu.astype(E.dtype))
    Phi_uu = jnp.einsum("ft,tij->fij", E, Ruu.astype(E.dtype))
    # G = Phi_yu Phi_uu^{-1}  ->  solve Phi_uu^T G^T = Phi_yu^T
    Gt = jnp.linalg.solve(jnp.swapaxes(Phi_uu, 1, 2), jnp.swapaxes(Phi_yu, 1, 2))
    return jnp.swapaxes(Gt, 1, 2)


def spectral_estimate(data: IOData, lag_window: int | None = None, omega: ArrayLike | None = None,
                      *, window: str = "hamming") -> tuple[np.ndarray, np.ndarray]:
    """Blackman–Tukey estimate of the frequency response from data (MATLAB `spa`).

    $\\hat G(e^{i\\omega T_s}) = \\hat\\Phi_{yu}(\\omega) \\hat\\Phi_u(\\omega)^{-1}$ with
    $\\hat\\Phi_{ab}(\\omega) = \\sum_{|\\tau| \\le M} W_M(\\tau) \\hat R_{ab}(\\tau) e^{-i\\omega\\tau T_s}$,
    Hamming lag window $W_M(\\tau) = 0.54 + 0.46 \\cos(\\pi\\tau/M)$ and by default
    $M = \\min(N/10, 30)$ (Ljung 1999, §6.4). Means are removed first.

    **Arguments:** `data`; `lag_window` M; `omega` in rad/s (default: 128 frequencies up to
    the Nyquist frequency, as `spa`); `window` `"hamming"` or `"hann"`
    ($W_M = 0.5 + 0.5\\cos(\\pi\\tau/M)$, the window MATLAB's `spa` uses).

    **Returns:** `(omega (nf,), G (nf, ny, nu))`, complex G, NumPy arrays.
    """
    if not isinstance(data, IOData):
        raise DataError(f"spectral_estimate: expected IOData, got {type(data).__name__}")
    N = data.n_samples
    M = min(N // 10, 30) if lag_window is None else lag_window
    if not isinstance(M, (int, np.integer)) or isinstance(M, bool) or not 1 <= M < N:
        raise DataError(f"spectral_estimate: lag window must be an integer in [1, {N - 1}], got {M!r}")
    if omega is None:
        omega = np.arange(1, 129) / 128 * np.pi / data.ts
    omega = np.asarray(omega, dtype=np.float64)
    if omega.ndim != 1 or not np.all(np.isfinite(omega)):
        raise DataError("spectral_estimate: omega must be a 1-D array of finite frequencies in rad/s")
    u = jnp.asarray(data.u)
    if bool(jnp.any(jnp.std(u, axis=0) == 0)):
        raise DataError("spectral_estimate: an input is constant: its spectrum is zero")
    if window not in _LAG_WINDOWS:
        raise DataError(f"spectral_estimate: window must be 'hamming' or 'hann', got {window!r}")
    G = np.asarray(_blackman_tukey(jnp.asarray(data.y), u, jnp.asarray(omega), int(M),
                                   float(data.ts), window))
    if not np.all(np.isfinite(G)):
        raise DataError("spectral_estimate: the input spectrum is singular (inputs linearly dependent?)")
    return omega, G


def bode(model: AbstractModel, omega: ArrayLike) -> dict:
    """Magnitude and phase of $G(e^{i\\omega T_s})$ from `model.frequency_response`.

    **Returns:** dict with `omega` (rad/s), `response` `(nf, ny, nu)` complex, `magnitude`
    (same units as the dc gain), `magnitude_db`, `phase_deg` (unwrapped along frequency).
    """
    omega = np.asarray(omega, dtype=np.float64)
    if omega.ndim != 1 or not np.all(np.isfinite(omega)) or np.any(omega < 0):
        raise DataError("bode: omega must be a 1-D array of non-negative frequencies in rad/s")
    G = np.asarray(model.frequency_response(jnp.asarray(omega)))
    mag = np.abs(G)
    with np.errstate(divide="ignore"):
        mag_db = 20 * np.log10(mag)
    phase = np.degrees(np.unwrap(np.angle(G), axis=0))
    return {"omega": omega, "response": G, "magnitude": mag, "magnitude_db": mag_db,
            "phase_deg": phase}


# ---------------------------------------------------------------- structure


def _pencil_zeros(A, B, C, D):
    """Finite generalised eigenvalues of the Rosenbrock pencil $[[A, B], [C, D]] - z [[I, 0], [0, 0]]$."""
    nx = A.shape[0]
    M = np.block([[A, B], [C, D]])
    Nm = np.zeros_like(M)
    Nm[:nx, :nx] = np.eye(nx)
    if nx == 0:
        return np.zeros(0, complex)
    alpha, beta = scipy.linalg.eigvals(M, Nm, homogeneous_eigvals=True)
    scale = max(1.0, float(np.abs(M).max()))
    tol = 1e3 * np.finfo(float).eps * scale
    finite = np.abs(beta) > tol * np.maximum(1.0, np.abs(alpha) / scale)
    if np.any((np.abs(alpha) < tol) & (np.abs(beta) < tol)):
        return None   # singular pencil: e.g. a zero transfer function
    z = alpha[finite] / beta[finite]
    return np.sort_complex(z)


def poles_zeros(model: AbstractModel) -> dict:
    """Poles and zeros of the model's state space.

    Transmission zeros (square systems) are the finite generalised eigenvalues of the
    Rosenbrock system matrix pencil $\\begin{bmatrix} A - zI & B \\\\ C & D \\end{bmatrix}$
    (Emami-Naeini & Van Dooren 1982); for non-square systems only the zeros of each SISO
    channel $G_{ij}$ are given. Zeros of a non-minimal realisation include its decoupling zeros.

    **Returns:** dict with `poles` `(nx,)`, `zeros` (transmission zeros, or None when
    ny != nu or the pencil is singular) and `channel_zeros` (`[i][j]` zeros of $G_{ij}$;
    None for an identically zero channel).
    """
    ss = model.to_statespace()
    A, B, C, D = (np.asarray(m, dtype=np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    poles = np.sort_complex(np.linalg.eigvals(A))
    zeros = _pencil_zeros(A, B, C, D) if D.shape[0] == D.shape[1] else None
    chan = [[_pencil_zeros(A, B[:, [j]], C[[i], :], D[[i]][:, [j]]) for j in range(D.shape[1])]
            for i in range(D.shape[0])]
    return {"poles": poles, "zeros": zeros, "channel_zeros": chan}


def step_info(model: AbstractModel, n: int, *, settling: float = 0.02) -> dict:
    """Step-response characteristics per channel (MATLAB `stepinfo`).

    For a unit step on input j at k = 0: the static gain $G_{ij}(1)$ (`model.dcgain`), the
    10–90 % rise time and the time after which the response stays within `settling` (2 %) of
    the gain, both in s, by linear interpolation between samples, and the overshoot in %.
    Channels with zero gain, or an unstable model, give NaN times.

    **Returns:** dict with `response` `(n, ny, nu)`, `t` `(n,)` s, `gain`, `rise_time`,
    `settling_time`, `overshoot_percent` (all `(ny, nu)`), `stable`.
    """
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool) or n < 2:
        raise DataError(f"step_info: n must be an integer >= 2, got {n!r}")
    s = np.asarray(model.step_response(int(n)), dtype=np.float64)      # (n, ny, nu)
    stable = bool(np.max(np.abs(np.asarray(model.poles()))) < 1.0) if model.n_states else True
    gain = np.asarray(model.dcgain(), dtype=np.float64) if stable else s[-1]
    ts = model.ts
    t = ts * np.arange(n)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(gain != 0, gain, np.nan)
        r = s / g                                      # normalised: tends to 1
    ny, nu = gain.shape
    rise = np.full((ny, nu), np.nan)
    settle = np.full((ny, nu), np.nan)
    over = np.full((ny, nu), np.nan)

    def crossing(x, level):
        idx = np.flatnonzero(x >= level)
        if idx.size == 0:
            return np.nan
        k = int(idx[0])
        if k == 0:
            return 0.0
        return ts * (k - 1 + (level - x[k - 1]) / (x[k] - x[k - 1]))

    for i in range(ny):
        for j in range(nu):
            x = r[:, i, j]
            if not stable or not np.all(np.isfinite(x)):
                continue
            rise[i, j] = crossing(x, 0.9) - crossing(x, 0.1)
            out = np.flatnonzero(np.abs(x - 1.0) > settling)
            if out.size == 0:
                settle[i, j] = 0.0
            elif out[-1] < n - 1:
                settle[i, j] = t[out[-1] + 1]
            over[i, j] = max(0.0, 100.0 * (float(np.max(x)) - 1.0))
    return {"response": s, "t": t, "gain": gain, "rise_time": rise, "settling_time": settle,
            "overshoot_percent": over, "stable": stable}


def rga(G: ArrayLike) -> Float[Array, "n n"]:
    """Relative gain array $\\Lambda = G \\circ (G^{-1})^T$ (Bristol 1966).

    For a 2×2 plant $\\lambda_{11} = 1/(1 - g_{12} g_{21}/(g_{11} g_{22}))$; rows and columns
    sum to 1. Pairings with $\\lambda_{ii}$ near 1 interact little.
    """
    G = jnp.asarray(G)
    if G.ndim != 2 or G.shape[0] != G.shape[1] or G.shape[0] == 0:
        raise ModelError(f"rga: G must be a square matrix, got shape {G.shape}")
    if not is_traced(G):
        Gn = np.asarray(G)
        if not np.all(np.isfinite(Gn)):
            raise ModelError("rga: G has non-finite entries")
        if np.linalg.cond(Gn) > 1.0 / (1e3 * np.finfo(Gn.dtype).eps):
            raise ModelError("rga: G is singular: the relative gain array is undefined")
    return G * jnp.linalg.inv(G).T


def steady_state_rga(model: AbstractModel) -> Float[Array, "n n"]:
    """RGA of the static gain `model.dcgain()` (thesis §3.4: pairing of heaters and sensors)."""
    if model.n_inputs != model.n_outputs:
        raise ModelError(f"steady_state_rga: needs as many inputs as outputs, got {model.n_inputs} "
                         f"inputs and {model.n_outputs} outputs")
    return rga(model.dcgain())


# ---------------------------------------------------------------- order selection


def information_criteria(cost: ArrayLike, n_params: ArrayLike, n_samples: int) -> dict:
    """Akaike's FPE and AIC and the Bayesian IC from the loss $V$ (Ljung 1999, §16.4).

    $\\mathrm{FPE} = V (1 + d/N)/(1 - d/N)$, $\\mathrm{AIC} = N \\ln V + 2d$,
    $\\mathrm{BIC} = N \\ln V + d \\ln N$, with d parameters and N samples. For several outputs
    pass $V = \\det \\hat\\Sigma_\\varepsilon$ (or a `(..., ny, ny)` residual covariance, whose
    determinant is taken). Broadcasts over a grid of candidates: smaller is better.

    **Returns:** dict with `fpe`, `aic`, `bic` (arrays of the broadcast shape).
    """
    V = jnp.asarray(cost)
    if V.ndim >= 2 and V.shape[-1] == V.shape[-2] and V.shape[-1] > 1:
        V = jnp.linalg.det(V)
    d = jnp.asarray(n_params)
    if not isinstance(n_samples, (int, np.integer)) or n_samples < 1:
        raise DataError(f"information_criteria: n_samples must be a positive integer, got {n_samples!r}")
    N = float(n_samples)
    if not is_traced(V) and not is_traced(d):
        if not bool(jnp.all(V > 0)) or not bool(jnp.all(jnp.isfinite(V))):
            raise DataError("information_criteria: the loss V must be positive and finite")
        if bool(jnp.any(d < 0)) or bool(jnp.any(d >= N)):
            raise DataError(f"information_criteria: the number of parameters must lie in [0, {n_samples})")
    logV = jnp.log(V)
    return {"fpe": V * (1 + d / N) / (1 - d / N), "aic": N * logV + 2 * d,
            "bic": N * logV + d * math.log(N)}
