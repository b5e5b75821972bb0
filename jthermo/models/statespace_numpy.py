"""NumPy twins of a linear model's simulation from its state-space realisation, for every model
whose `simulate` is that realisation's (`StateSpace`, `BedModel`, `ExtendedBedModel`, ...;
`Polynomial` has its own filters in `polynomial_numpy`).

In a fresh process each JAX function of a small model compiles once per shape: the validation
of a grey-box bed (`validate.compare`: its realisation, the simulation, the Jacobian of the
simulation in the initial state, the least squares) was about 50 XLA compiles and most of a
cold `jthermo fit --model greybox` (measured by `python benchmarks/fit_profile.py`). Here the
realisation is one compiled program (`realise`, shared with the plausibility check) and the
rest runs on the host in float64:

$$x_{t+1} = A x_t + B (u_t - u_0) + B_w (w_t - w_0), \\qquad y_t = y_0 + C x_t + D (u_t - u_0),$$

and the least-squares initial state of $y_t = \\hat y_t^{(0)} + C A^t x_0$ (the output is
affine in $x_0$), as `validate.estimate_initial_state` computes it.
"""

from __future__ import annotations

import equinox as eqx
import numpy as np

from ._base import AbstractModel, StateSpace
from .polynomial import Polynomial


@eqx.filter_jit
def realise(model: AbstractModel) -> StateSpace:
    """`model.to_statespace()` as one compiled program (eagerly, a realisation compiles op by
    op, about ten times the compiled program's CPU time in a fresh process)."""
    return model.to_statespace()


def supported(model) -> bool:
    """True when `model.simulate` and `model.initial_state` are its realisation's (every
    `AbstractModel` that overrides neither, and `StateSpace` itself)."""
    if isinstance(model, Polynomial) or not isinstance(model, AbstractModel):
        return False
    if isinstance(model, StateSpace):
        return True
    cls = type(model)
    return cls.simulate is AbstractModel.simulate and cls.initial_state is AbstractModel.initial_state


def arrays(model: AbstractModel) -> dict[str, np.ndarray]:
    """The realisation's matrices and operating point as float64 NumPy arrays."""
    ss = model if isinstance(model, StateSpace) else realise(model)
    return {k: np.asarray(getattr(ss, k), np.float64)
            for k in ("A", "B", "C", "D", "Bw", "u0", "w0", "y0")}


def _deviations(m, u, w):
    du = np.asarray(u, np.float64) - m["u0"]
    nw = m["Bw"].shape[1]
    dw = (np.asarray(w, np.float64)[:, :nw] - m["w0"]) if nw else np.zeros((du.shape[0], 0))
    return du, dw


def simulate(m: dict, u, w=None, x0=None) -> np.ndarray:
    """`StateSpace.simulate(u, w, x0)` of the realisation `m` (`arrays`), `(T, ny)`."""
    du, dw = _deviations(m, u, w)
    A = m["A"]
    drive = du @ m["B"].T + dw @ m["Bw"].T
    xs = np.empty((du.shape[0], A.shape[0]))
    x = np.zeros(A.shape[0]) if x0 is None else np.asarray(x0, np.float64)
    for t in range(du.shape[0]):
        xs[t] = x
        x = A @ x + drive[t]
    return m["y0"] + xs @ m["C"].T + du @ m["D"].T


def free_response(m: dict, T: int) -> np.ndarray:
    """$C A^t$ for t = 0..T-1, `(T, ny, nx)`: how the initial state shows in the output."""
    A, C = m["A"], m["C"]
    out = np.empty((T,) + C.shape)
    P = C.copy()
    for t in range(T):
        out[t] = P
        P = P @ A
    return out


def initial_state(model: AbstractModel, y, u, w=None) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares initial state and the simulation from it, `(x0 (nx,), yhat (T, ny))`, as
    `validate.estimate_initial_state` computes it for a linear model (column-scaled normal
    equations), kept only when it simulates the data at least as well as the steady state
    consistent with the first measurement (`model.initial_state(y[0])`)."""
    m = arrays(model)
    y = np.asarray(y, np.float64)
    T, ny = y.shape
    y_ref = simulate(m, u, w)
    O = free_response(m, T).reshape(T * ny, -1)
    scale = np.sqrt(np.sum(O ** 2, axis=0))
    scale = np.where(scale > 0, scale, 1.0)
    On = O / scale
    dx = np.linalg.lstsq(On.T @ On, On.T @ (y - y_ref).reshape(T * ny), rcond=None)[0] / scale
    y_ls = y_ref + (O @ dx).reshape(T, ny)
    x_fb = np.linalg.lstsq(m["C"], y[0] - m["y0"], rcond=None)[0]
    y_fb = y_ref + (O @ x_fb).reshape(T, ny)
    if np.all(np.isfinite(dx)) and np.sum((y - y_ls) ** 2) <= np.sum((y - y_fb) ** 2):
        return dx, y_ls
    return x_fb, y_fb


__all__ = ["arrays", "free_response", "initial_state", "realise", "simulate", "supported"]
