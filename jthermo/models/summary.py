"""Readable text of a model, for `print(model)` and `FitResult.summary`: its inputs, outputs
and sample time, the static gain $G(1) = C (I - A)^{-1} B + D$ and the poles (eigenvalues of
A, z-plane), instead of the array shapes of the default `equinox` repr."""

from __future__ import annotations

import numpy as np


def gain_and_poles(model) -> list[str]:
    """Two lines: the DC gain (°C per input) and the sorted poles of `model`'s state space."""
    ss = model.to_statespace()
    poles = np.linalg.eigvals(np.asarray(ss.A, np.float64))
    return [f"  DC gain (°C per input): {np.round(np.asarray(ss.dcgain(), np.float64), 4).tolist()}",
            (f"  poles ({poles.size}, z-plane, Ts {float(ss.ts):g} s): "
             f"{np.round(np.sort_complex(poles), 4).tolist()}")]


def describe(model) -> str:
    """`Name: nu inputs -> ny outputs, Ts s` and `gain_and_poles`; a model holding traced
    values (inside `jit`) or one without a state-space view gets the `equinox` tree text."""
    import equinox as eqx

    try:
        head = (f"{type(model).__name__}: {int(model.n_inputs)} inputs -> "
                f"{int(model.n_outputs)} outputs, Ts {float(model.ts):g} s")
        return "\n".join([head, *gain_and_poles(model)])
    except Exception:  # noqa: BLE001 - printing never fails: fall back to the tree
        return eqx.tree_pformat(model)


__all__ = ["describe", "gain_and_poles"]
