"""jthermo: identify thermal models of multi-zone heated systems and tune their controllers in JAX.

The top-level names are imported lazily (PEP 562), so `import jthermo` and `jthermo --help`
do not pay for importing JAX; `jthermo.IOData` and friends load their module on first use.
"""

import importlib

__version__ = "0.1.0"

from .errors import (  # noqa: E402 - JAX-free, cheap
    ConfigError as ConfigError,
    ControlError as ControlError,
    DataError as DataError,
    FitError as FitError,
    JThermoError as JThermoError,
    ModelError as ModelError,
)

#: public name -> (module, attribute or None for the module itself)
_LAZY = {
    "data": ("jthermo.data", None),
    "inputs": ("jthermo.inputs", None),
    "validate": ("jthermo.validate", None),
    "IOData": ("jthermo.data", "IOData"),
    "AbstractModel": ("jthermo.models", "AbstractModel"),
    "StateSpace": ("jthermo.models", "StateSpace"),
    "prbs": ("jthermo.inputs", "prbs"),
    "compare": ("jthermo.validate", "compare"),
    "fit_percent": ("jthermo.validate", "fit_percent"),
    "residual_tests": ("jthermo.validate", "residual_tests"),
    "fit": ("jthermo.identify.fit", "fit"),
}


def __getattr__(name: str):
    if name not in _LAZY:
        raise AttributeError(f"module 'jthermo' has no attribute {name!r}")
    module, attr = _LAZY[name]
    value = importlib.import_module(module)
    value = value if attr is None else getattr(value, attr)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
