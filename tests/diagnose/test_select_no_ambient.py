"""Diagnosis without a measured ambient: no `w_` column, so the surroundings are estimated.

Both TCLab records in `../shared/data/real/` are like this. The synthetic records have the
real records' shape (2 x 2, 600 + 600 samples at 1 s), so the real-record test reuses the
compiled fits instead of paying for its own.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from jthermo.diagnose import MECHANISMS, diagnose, to_json
from tests.diagnose.records import DELAY, record

N_EST = N_VAL = 600
TCLAB = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real" / "tclab_cace2020"


def _finite(xs):
    return all(math.isfinite(x) for x in xs)


def _sensible(res):
    """What every diagnosis must give: finite fits, findings from the library, an augmented
    model made of findings only."""
    assert _finite(res["baseline"]["fit_percent"]) and _finite(res["augmented"]["fit_percent"])
    names = [f["mechanism"] for f in res["findings"]]
    assert set(names) <= set(MECHANISMS) and set(res["augmented"]["mechanisms"]) <= set(names)
    assert all(0 < f["confidence"] <= 1 for f in res["findings"])


@pytest.fixture(scope="module")
def results():
    out = {}
    for k, eff in enumerate([None, "input_delay"]):
        est, val = record(eff, k, n_est=N_EST, n_val=N_VAL, ambient=False)
        assert est.signal_names == () and val.signal_names == ()
        out[eff] = to_json(diagnose(est, val))
    return out


def test_null_without_ambient_has_no_finding(results):
    res = results[None]
    _sensible(res)
    assert res["verdict"] == "no_significant_mismatch" and res["findings"] == []
    # the estimated surroundings leave the plain bed model as good as it is
    assert min(res["baseline"]["fit_percent"]) > 90.0


def test_delay_without_ambient_is_found(results):
    res = results["input_delay"]
    _sensible(res)
    assert res["verdict"] == "mismatch"
    assert res["findings"][0]["mechanism"] == "input_delay"
    assert res["augmented"]["mechanisms"] == ["input_delay"]
    assert res["findings"][0]["parameters"]["delay_s"] == pytest.approx(DELAY, abs=0.5)
    assert min(res["augmented"]["fit_percent"]) > 85.0
    assert res["augmented"]["mean_fit_percent"] >= res["baseline"]["mean_fit_percent"] + 2.0


def test_tclab_record_without_ambient():
    """The TCLab two-heater identification and validation runs (Park et al. 2020): a real
    record whose known physics (sensor lag, heater-heater exchange, radiation) the baseline
    leaves out, so a sensible diagnosis finds something that improves the validation fit."""
    if not TCLAB.is_dir():
        pytest.skip(f"{TCLAB} is absent (a clone without ../shared)")
    from jthermo.data import load

    est = load(TCLAB / "id_2heaters" / "data.csv")
    val = load(TCLAB / "val_2heaters" / "data.csv")
    assert est.signal_names == () and (est.n_samples, est.n_outputs) == (N_EST, 2)
    res = to_json(diagnose(est, val))
    _sensible(res)
    assert res["verdict"] == "mismatch" and res["findings"]
    assert res["augmented"]["mean_fit_percent"] >= res["baseline"]["mean_fit_percent"] + 5.0
    assert np.all(np.asarray(res["augmented"]["fit_percent"]) > 70.0)
