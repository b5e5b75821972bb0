"""jthermo: identify thermal models of multi-zone heated systems and tune their controllers in JAX."""

__version__ = "0.1.0"

from . import data as data
from .data import IOData as IOData
from .errors import (
    ConfigError as ConfigError,
    ControlError as ControlError,
    DataError as DataError,
    FitError as FitError,
    JThermoError as JThermoError,
    ModelError as ModelError,
)
from .models import AbstractModel as AbstractModel, StateSpace as StateSpace
from . import inputs as inputs
from . import validate as validate
from .inputs import prbs as prbs
from .validate import compare as compare
from .validate import fit_percent as fit_percent
from .validate import residual_tests as residual_tests
