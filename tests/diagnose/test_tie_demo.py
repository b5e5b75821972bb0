"""The demo's loop section (`jthermo.diagnose.tie_demo`): a tie on the virtual printer, one
designed experiment, and an outcome read from the run."""

import pytest

from jthermo.diagnose import tie_demo as T

pytestmark = pytest.mark.filterwarnings("ignore")


def _r(named, conf, rivals, why="x"):
    return {"records": 1, "named": named, "confidence": conf, "rivals": rivals, "next": why}


def test_the_outcome_says_what_the_rounds_show_never_a_settled_tie_that_was_not():
    tied = _r("heater_lag", 0.4, ["input_delay"], "`heater_lag` is uncertain")
    sure = _r("heater_lag", 0.999, [])
    assert T.outcome([sure], False, True, "heater_lag").startswith("no tie to settle")
    assert T.outcome([_r(None, None, [])], False, True, "heater_lag") == \
        "no tie to settle: the first records name nothing"
    assert T.outcome([tied, tied], True, False, "heater_lag").startswith("the tie is still open after 1")
    s = T.outcome([tied, sure], True, True, "heater_lag")
    assert s.startswith("one designed experiment settled the tie: `heater_lag`") and "but" not in s
    wrong = T.outcome([tied, _r("input_delay", 0.99, [])], True, True, "heater_lag")
    assert wrong.endswith("but the concealed effect was `heater_lag`")


def test_the_demo_case_ties_and_one_designed_experiment_settles_it():
    """The demo's printer case: the first records leave the lag tied with the dead time; the
    designed record, run on the printer and diagnosed with the first two pooled, names the lag
    with no rival left (this fails if the loop did not settle the tie)."""
    S = T.settle_tie(0)
    first, last = S["rounds"][0], S["rounds"][-1]
    assert S["tie"] and first["rivals"] == ["input_delay"]
    assert S["settled"] and len(S["rounds"]) == 2 and last["records"] == 2
    assert last["named"] == "heater_lag" and last["rivals"] == [] and last["confidence"] >= 0.95
    assert S["named_truth"] and S["outcome"].startswith("one designed experiment settled the tie")
    assert S["experiment"]["separation_designed"] >= S["experiment"]["separation_prbs"]
