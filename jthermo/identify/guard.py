"""Checks on a fitted model before `fit` returns it: never a silent wrong answer.

A fitted model passes when (1) its state-space realisation is stable (spectral radius
below 1: the realisation is what simulation from an estimated initial state, validation and
control design use), (2) its simulation from inputs alone is finite on the estimation data, and
(3) its simulation fit on the estimation data is not far below that of a trivial reference, the
ARX estimate of the same data (the start point of every PEM fit):

$$\\mathrm{fit} = 100\\,\\Big(1 - \\frac{\\lVert y - \\hat y\\rVert}{\\lVert y - \\bar y\\rVert}\\Big)
  \\ge \\mathrm{fit}_{\\mathrm{ARX}} - \\texttt{margin} \\quad(\\text{mean over outputs}).$$

A reference that is itself unstable or non-finite sets no bar.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..data import IOData
from ..models import polynomial_numpy

#: how far (fit %, estimation data) a model may lie below its ARX reference
REFERENCE_MARGIN = 10.0


@eqx.filter_jit
def _simulate(model, u, w):
    return model.simulate(u, w)


def simulation_fit(model, data: IOData) -> float:
    """Mean simulation fit % of `model` on `data`, from the model's rest (no initial-state
    estimate); `-inf` when the simulation is not finite."""
    if polynomial_numpy.supported(model):     # NumPy filters: nothing to compile
        yhat = polynomial_numpy.simulate(model, data.u)
    else:
        w = data.w[:, :model.n_signals] if model.n_signals else None
        yhat = np.asarray(_simulate(model, jnp.asarray(data.u), None if w is None else jnp.asarray(w)))
    if not np.all(np.isfinite(yhat)):
        return float("-inf")
    y = np.asarray(data.y)
    num = np.linalg.norm(y - yhat, axis=0)
    den = np.maximum(np.linalg.norm(y - y.mean(axis=0), axis=0), np.finfo(float).tiny)
    return float(np.mean(100.0 * (1.0 - num / den)))


def spectral_radius(model) -> float:
    """Largest pole magnitude of the model's state-space realisation (0 without states,
    `inf` when the realisation is not finite; for a diagonal-A polynomial model the largest
    root of its denominators, the same poles without building the realisation)."""
    if polynomial_numpy.supported(model):
        return polynomial_numpy.spectral_radius(model)
    A = np.asarray(model.to_statespace().A)
    if A.size == 0:
        return 0.0
    if not np.all(np.isfinite(A)):
        return float("inf")
    return float(np.max(np.abs(np.linalg.eigvals(A))))


@dataclasses.dataclass(frozen=True)
class FitCheck:
    """Outcome of `check_model`.

    **Fields:** `spectral_radius` (largest pole magnitude), `fit` (simulation fit % on the
    estimation data, `-inf` when not finite), `reference_fit` (the ARX reference's, `nan`
    when there is none or it sets no bar), `margin`.
    """

    spectral_radius: float
    fit: float
    reference_fit: float = float("nan")
    margin: float = REFERENCE_MARGIN

    @property
    def stable(self) -> bool:
        return bool(self.spectral_radius < 1.0)

    @property
    def finite(self) -> bool:
        return bool(np.isfinite(self.fit))

    @property
    def above_reference(self) -> bool:
        return bool(not np.isfinite(self.reference_fit) or self.fit >= self.reference_fit - self.margin)

    @property
    def ok(self) -> bool:
        return self.stable and self.finite and self.above_reference

    def reason(self) -> str:
        """What failed, in a few words ('' when the model passed)."""
        if not self.stable:
            return f"the model is unstable (largest pole magnitude {self.spectral_radius:.4g})"
        if not self.finite:
            return "the model's simulation is not finite on the estimation data"
        if not self.above_reference:
            return (f"the model simulates the estimation data at {self.fit:.1f} %, far below the "
                    f"ARX reference's {self.reference_fit:.1f} %")
        return ""

    def to_dict(self) -> dict:
        return {"stable": self.stable, "finite": self.finite,
                "spectral_radius": self.spectral_radius, "estimation_fit": self.fit,
                "reference_fit": None if not np.isfinite(self.reference_fit) else self.reference_fit,
                "passed": self.ok}


def check_model(model, data: IOData, reference=None, *, margin: float = REFERENCE_MARGIN) -> FitCheck:
    """Stability, finiteness and the reference comparison of a fitted `model` on its
    estimation `data`; `reference` is a trivial model of the same data (the ARX estimate) or
    None."""
    rho = spectral_radius(model)
    fit = simulation_fit(model, data) if rho < 1.0 else float("-inf")
    ref = float("nan")
    if reference is not None and spectral_radius(reference) < 1.0:
        ref = simulation_fit(reference, data)
    return FitCheck(spectral_radius=rho, fit=fit, reference_fit=ref if np.isfinite(ref) else float("nan"),
                    margin=margin)


__all__ = ["REFERENCE_MARGIN", "FitCheck", "check_model", "simulation_fit", "spectral_radius"]
