"""Accuracy and ±3σ coverage on data from a known model of each family (N = 4 zones).

The data and true models come from `experiments/identification_coverage.py` (its full run,
10 seeds × T = 6000, is the published study); here a few seeds, shorter records for the fast
ones.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from jthermo.data import from_arrays
from jthermo.identify.fit import fit

_PATH = Path(__file__).resolve().parents[2] / "experiments" / "identification_coverage.py"
_spec = importlib.util.spec_from_file_location("identification_coverage", _PATH)
study = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(study)


def _one(family, seed, T):
    true, _ = study.true_model(family)
    u, y = study.dataset(family, T, seed, 1)
    uv, yv = study.dataset(family, T, seed, 2)
    # the family's own estimator and parameters, not the heat path's positive realisation
    res = fit(from_arrays(u, y), family, study.ORDERS[family], physics="none",
              **study.FIT_OPTIONS.get(family, {}))
    gap = study.fit_percent(yv, study.simulate(true, uv)) - \
        study.fit_percent(yv, study.simulate(res.model, uv))
    est, std = study.estimated_parameters(family, res)
    inside = np.abs(est - study.true_parameters(family, res)) <= 3 * std
    return gap, inside


@pytest.mark.parametrize("family", ["arx", "ss"])
def test_known_model_fit_and_coverage(family):
    gap, inside = _one(family, seed=0, T=3000)
    assert gap < 1.0
    assert inside.mean() >= 0.9


@pytest.mark.slow
@pytest.mark.parametrize("family", list(study.FAMILIES))
def test_known_model_fit_and_coverage_over_seeds(family):
    gaps, inside = zip(*(_one(family, seed, 6000) for seed in range(3)))
    # SS seed 1 is 1.04 points below the true model (sampling error of the DC gain: all its
    # parameters are inside 3 sigma); the others are within 1 point
    assert np.mean(gaps) < 1.0 and max(gaps) < 1.5
    assert np.concatenate(inside).mean() >= 0.95
