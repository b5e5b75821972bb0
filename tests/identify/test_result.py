"""The family registry: every model family has exactly one fitter, and `fit` dispatches to it."""

import numpy as np
import pytest

from jthermo.data import from_arrays
from jthermo.errors import ConfigError
from jthermo.identify.fit import fit  # importing the dispatcher loads every fitter
from jthermo.identify.greybox import fit_greybox
from jthermo.identify.polynomial import fit_polynomial
from jthermo.identify.result import FAMILIES, FITTERS, register_fitter
from jthermo.identify.statespace import fit_statespace


def test_every_family_has_its_fitter():
    assert set(FITTERS) == set(FAMILIES)
    for family in ("arx", "armax", "oe", "bj"):
        assert FITTERS[family].options is fit_polynomial
    assert FITTERS["ss"].options is fit_statespace
    assert FITTERS["greybox"].options is fit_greybox


def test_register_fitter_rejects_an_unknown_family():
    with pytest.raises(ValueError, match="unknown model family"):
        register_fitter(("nope",), options=fit_polynomial)(lambda *a, **k: None)
    assert "nope" not in FITTERS


def test_unknown_option_is_a_config_error():
    rng = np.random.default_rng(0)
    data = from_arrays(rng.standard_normal((100, 1)), rng.standard_normal((100, 1)))
    for family, orders in (("arx", (1, 1, 1)), ("ss", (1,)), ("greybox", ())):
        with pytest.raises(ConfigError, match=f"unknown option `bogus` for family {family}"):
            fit(data, family, orders, bogus=1)
