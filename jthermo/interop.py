"""Exchange models with python-control and SciPy.

Every jthermo model converts through its innovations state space. Exports describe the
deterministic part (u, and the measured signals w as extra inputs when the model has any):
`x_{k+1} = A x_k + [B  B_w] [ũ; w̃]`, `y = C x + [D  0] [ũ; w̃]`, in deviations from the
operating point (`u0`, `w0`, `y0`), which is lost in the export. Imports give a
`StateSpace` with zero operating point and zero Kalman gain.

python-control works with `(n, T)` signal arrays; jthermo with `(T, n)`: transpose when you
feed signals between them.
"""

from __future__ import annotations

import numpy as np

from .errors import ConfigError, ModelError
from .models._base import AbstractModel, StateSpace


def _matrices(model: AbstractModel, include_signals: bool):
    if not isinstance(model, AbstractModel):
        raise ModelError(f"expected a jthermo model, got {type(model).__name__}")
    ss = model.to_statespace()
    A, B, C, D = (np.asarray(m, dtype=np.float64) for m in (ss.A, ss.B, ss.C, ss.D))
    Bw = np.asarray(ss.Bw, dtype=np.float64)
    if include_signals and Bw.shape[1]:
        B = np.hstack([B, Bw])
        D = np.hstack([D, np.zeros((D.shape[0], Bw.shape[1]))])
    return A, B, C, D, float(ss.ts), Bw.shape[1] if include_signals else 0


def _names(model, nu: int, nw: int, ny: int):
    u = [f"u{i + 1}" for i in range(nu - nw)] + [f"w{i + 1}" for i in range(nw)]
    return u, [f"y{i + 1}" for i in range(ny)]


def to_control(model: AbstractModel, *, include_signals: bool = True):
    """The model as a discrete-time `control.StateSpace` with `dt = ts`.

    **Arguments:**
    - `model`: any jthermo model.
    - `include_signals`: append the measured signals `w` as inputs after `u` (names `w1`...).
    """
    import control

    A, B, C, D, ts, nw = _matrices(model, include_signals)
    inputs, outputs = _names(model, B.shape[1], nw, C.shape[0])
    return control.ss(A, B, C, D, dt=ts, inputs=inputs, outputs=outputs)


def to_transfer_function(model: AbstractModel, *, include_signals: bool = True):
    """The model as a discrete-time `control.TransferFunction` (MIMO: one SISO entry per pair)."""
    import control

    return control.ss2tf(to_control(model, include_signals=include_signals))


def to_dlti(model: AbstractModel, *, include_signals: bool = True):
    """The model as a `scipy.signal.dlti` in state-space form with `dt = ts`."""
    from scipy import signal

    A, B, C, D, ts, _ = _matrices(model, include_signals)
    return signal.dlti(A, B, C, D, dt=ts)


def _check_dt(dt) -> float:
    if dt is None or dt is True or dt == 0:
        raise ConfigError("cannot import a continuous-time or unspecified-sample-time system: "
                          "discretise it first (e.g. control.sample_system)")
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise ConfigError(f"cannot import a system with sample time {dt}")
    return dt


def _statespace(A, B, C, D, ts) -> StateSpace:
    import jax.numpy as jnp

    A, B, C, D = (np.atleast_2d(np.asarray(m, dtype=np.float64)) for m in (A, B, C, D))
    if A.size == 0:  # a static gain: one state that does nothing keeps shapes valid
        A = np.zeros((1, 1))
        B = np.zeros((1, D.shape[1]))
        C = np.zeros((D.shape[0], 1))
    for name, m in (("A", A), ("B", B), ("C", C), ("D", D)):
        if not np.isfinite(m).all():
            raise ModelError(f"cannot import a system whose `{name}` has NaN or inf")
    return StateSpace(jnp.asarray(A), jnp.asarray(B), jnp.asarray(C), jnp.asarray(D), ts=ts)


def from_control(sys) -> StateSpace:
    """A `StateSpace` from a discrete-time `control.StateSpace` or `control.TransferFunction`."""
    import control

    if isinstance(sys, control.TransferFunction):
        try:
            sys = control.tf2ss(sys)
        except Exception as exc:  # MIMO realisation may need slycot
            raise ConfigError(f"cannot realise this transfer function as a state space ({exc})") from None
    if not isinstance(sys, control.StateSpace):
        raise ConfigError(f"expected a control.StateSpace or TransferFunction, got {type(sys).__name__}")
    ts = _check_dt(sys.dt)
    return _statespace(sys.A, sys.B, sys.C, sys.D, ts)


def from_dlti(sys) -> StateSpace:
    """A `StateSpace` from a `scipy.signal.dlti` (state-space, transfer-function or zpk form)."""
    from scipy import signal

    if not isinstance(sys, signal.dlti):
        raise ConfigError(f"expected a scipy.signal.dlti, got {type(sys).__name__}")
    ts = _check_dt(sys.dt)
    s = sys.to_ss()
    return _statespace(s.A, s.B, s.C, s.D, ts)
