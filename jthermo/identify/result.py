"""What every fitter returns (`FitResult`), and which fitter serves which model family.

`fit` (`jthermo.identify.fit`) is one entry point for every family; the fitters below it
(`polynomial.py`: arx, armax, oe, bj; `statespace.py`: ss; `greybox.py`: greybox) import this
module and register themselves with `register_fitter`, so that `fit` finds each family's fitter
in `FITTERS` and no fitter imports the dispatcher.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, NamedTuple

from ..data import IOData
from ..families import MODEL_FAMILIES, ORDER_NAMES
from ..models.summary import gain_and_poles

FAMILIES = MODEL_FAMILIES


@dataclasses.dataclass(frozen=True)
class FitResult:
    """Outcome of `fit`.

    **Fields:**
    - `model`: the fitted model (an `AbstractModel`, absolute units).
    - `family`, `orders`: the family name and its orders (`{"na": 2, "nb": 2, "nk": 1}`).
    - `converged`: every PEM problem reported success (always True for ARX least squares).
    - `cost`: mean squared one-step prediction error (simulation error for OE) on the
      estimation data. `seconds`: wall time of the fit, compilation included.
    - `criterion_table`: when orders were chosen automatically, one dict per candidate.
    - `covariance`, `std`: parameter covariance and standard deviations; for polynomial
      families per output, `(ny, p, p)` / `(ny, p)` in the layout of
      `Polynomial.flat_coefficients`.
    - `x0`: an estimated initial state where the family estimates one; `extra`: anything else.
    - `envelope`: what the recording says about the plant (`models.Envelope`: sample time,
      recorded range, input limits, rest level, noise), set by `fit`.
    """

    model: Any
    family: str = ""
    orders: dict = dataclasses.field(default_factory=dict)
    converged: bool = True
    cost: float = float("nan")
    seconds: float = float("nan")
    criterion_table: list | None = None
    covariance: Any = None
    std: Any = None
    x0: Any = None
    extra: dict = dataclasses.field(default_factory=dict)
    envelope: Any = None

    @classmethod
    def from_pem(cls, model, res, *, seconds: float = float("nan"), data: IOData | None = None,
                 info: dict | None = None, family: str = "greybox",
                 orders: dict | None = None) -> "FitResult":
        """Wrap a model and its `PEMResult` (used by families fitted outside this module)."""
        del data
        return cls(model=model, family=family, orders=dict(orders or {}),
                   converged=bool(res.converged), cost=float(res.cost), seconds=float(seconds),
                   covariance=res.covariance, std=res.std, extra=dict(info or {}))

    def __repr__(self) -> str:
        return self.summary()

    def summary(self) -> str:
        """A readable summary: family, orders, convergence, cost, fit % where the fitter
        reports one, the model's static gain $G(1)$ and its poles (no covariance arrays)."""
        import numpy as np

        lines = [f"FitResult: {self.family or type(self.model).__name__} {self.orders}, "
                 f"{'converged' if self.converged else 'NOT converged'}, cost {self.cost:.4g}, "
                 f"{self.seconds:.3g} s"]
        if "fit_percent" in self.extra:
            lines.append(f"  fit %: {np.round(np.asarray(self.extra['fit_percent']), 2).tolist()}")
        try:
            lines.extend(gain_and_poles(self.model))
        except Exception as exc:  # noqa: BLE001 - a summary never fails on an odd model
            lines.append(f"  (no state-space view: {type(exc).__name__})")
        return "\n".join(lines)


class Fitter(NamedTuple):
    """How `fit` runs the fitter of a model family.

    **Fields:**
    - `run`: `run(data, family, orders, *, seed, n_starts, progress, **options)` returns a
      `FitResult`. `orders` is a dict in MATLAB's naming (`ORDER_NAMES[family]`), or None
      where the fitter chooses the orders itself (`fit` chooses polynomial orders over a grid
      first). A `FitResult` whose `seconds` is NaN gets the wall time of the whole `fit` call.
    - `options`: the public fitter whose keyword arguments are the family's options (`fit`
      answers any other option with a one-line `ConfigError`).
    """

    run: Callable[..., FitResult]
    options: Callable


#: family name -> its `Fitter`, filled by `register_fitter` when the fitter modules load
FITTERS: dict[str, Fitter] = {}


def register_fitter(families: tuple[str, ...], options: Callable):
    """Decorator: `run` (see `Fitter`) fits every family of `families`, with the options of
    the fitter `options`."""
    def decorate(run: Callable[..., FitResult]) -> Callable[..., FitResult]:
        for family in families:
            if family not in FAMILIES:
                raise ValueError(f"register_fitter: unknown model family {family!r}")
            FITTERS[family] = Fitter(run, options)
        return run
    return decorate


__all__ = ["FAMILIES", "FITTERS", "ORDER_NAMES", "FitResult", "Fitter", "register_fitter"]
