"""Additions of one forward-selection round that explain the same residual are rivals."""

import numpy as np

from jthermo.diagnose import decide as D
from jthermo.diagnose.joint import rival_additions, rivals_among


def _model(e, mechs):
    return {"e": e, "set": ("heater_lag", *mechs)}


def test_a_tied_addition_is_a_rival_a_beaten_one_is_not():
    rng = np.random.default_rng(3)
    T = 1500
    e_best = 0.05 * rng.standard_normal((T, 2))
    tied = e_best + 0.002 * rng.standard_normal((T, 2))        # the same residual, to rounding
    beaten = 1.5 * e_best + 0.02 * rng.standard_normal((T, 2))
    k_val = lambda s: 0
    out = rival_additions(_model(e_best, ("input_nonlinearity",)),
                          [("radiative_loss", _model(tied, ("radiative_loss",))),
                           ("heat_accumulation", _model(beaten, ("heat_accumulation",)))], k_val)
    assert out["rivals"] == ["radiative_loss"]
    # the z over the closest addition is the tied one's, and the finding is then uncertain
    assert D.uncertain(D.confidence(8.0, out["z_over_runner"]))
    alone = rival_additions(_model(e_best, ("input_nonlinearity",)),
                            [("heat_accumulation", _model(beaten, ("heat_accumulation",)))], k_val)
    assert alone["rivals"] == [] and not D.uncertain(D.confidence(8.0, alone["z_over_runner"]))
    none = rival_additions(_model(e_best, ()), [], k_val)
    assert none["rivals"] == [] and none["z_over_runner"] is None
    # a tied addition that joined the augmented model in a later round is no alternative to it
    later = rivals_among(out["z_over"], ("heater_lag", "input_nonlinearity", "radiative_loss"))
    assert later["rivals"] == [] and later["z_over_runner"] == out["z_over"]["heat_accumulation"]
