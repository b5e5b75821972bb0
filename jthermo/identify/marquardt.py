"""Marquardt's damping rule, the one rule of jthermo's Levenberg–Marquardt solvers that try one
damped step an iteration: the NumPy polynomial solver (`pem_numpy.lm_row`) and the matrix-free
solver (`matrix_free.MatrixFreeLM`).

A step that lowers the cost is taken and the damping $\\lambda$ divided by `LAMBDA_DOWN` (not
below the solver's floor); a refused step multiplies it by `LAMBDA_UP`, so a solve from
$\\lambda_0$ = `LAMBDA0` alternates between Gauss–Newton steps where the model is nearly linear
and short gradient steps where it is not. Written on an array namespace `xp` (NumPy or
`jax.numpy`): the NumPy solver and the compiled one run the same rule. The diagnosis's masked
solver (`lm.MaskedLM`) tries three dampings a round instead and keeps its own rule.
"""

from __future__ import annotations

import numpy as np

#: the damping's start; a taken step divides it by `LAMBDA_DOWN`, a refused one multiplies it
#: by `LAMBDA_UP`
LAMBDA0, LAMBDA_DOWN, LAMBDA_UP = 1e-3, 3.0, 4.0


def next_damping(lam, better, floor: float, xp=np):
    """The damping after a trial step: $\\max(\\lambda / 3, \\lambda_{min})$ if the step lowered
    the cost (`better`), else $4\\lambda$."""
    return xp.where(better, xp.maximum(lam / LAMBDA_DOWN, floor), lam * LAMBDA_UP)


__all__ = ["LAMBDA0", "LAMBDA_DOWN", "LAMBDA_UP", "next_damping"]
