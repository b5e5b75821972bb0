"""An addition whose joint fit stopped short is not beaten (`joint.unfitted_additions`).

A nested model at its optimum is never worse than the model it contains; an addition that ends
above the smaller model's cost beyond chance was not fitted, its mechanism not tested, and the
addition chosen in its round is named with it as a rival, not confidently.
"""

from jthermo.diagnose import decide as D
from jthermo.diagnose.joint import rivals_among, unfitted_additions


def _t(lr, crit=10.2):
    return {"estimation_lr": lr, "estimation_lr_critical": crit}


def test_an_addition_far_above_the_smaller_models_cost_is_a_tie():
    judged = [("input_delay", _t(-259.9)), ("input_nonlinearity", _t(2648.1)),
              ("ambient_variation", _t(-4.0)), ("radiative_loss", _t(-1296.9, 12.0))]
    assert unfitted_additions(judged) == {"input_delay": 0.0, "radiative_loss": 0.0}
    tie = rivals_among(unfitted_additions(judged), ())
    assert tie["rivals"] == ["input_delay", "radiative_loss"] and tie["z_over_runner"] == 0.0
    # the chosen addition's confidence (`select.findings_of`): uncertain, whatever its own z
    assert D.uncertain(D.confidence(9.21, tie["z_over_runner"]))
    # one that joins the model later is no rival of it
    assert rivals_among(unfitted_additions(judged), ("heater_lag", "input_delay"))["rivals"] == ["radiative_loss"]


def test_additions_within_chance_of_the_smaller_model_leave_the_confidence():
    judged = [("input_delay", _t(-9.1, 12.0)), ("heat_accumulation", _t(11.3, 23.0))]
    assert unfitted_additions(judged) == {}
    tie = rivals_among(unfitted_additions(judged), ())
    assert tie["rivals"] == [] and tie["z_over_runner"] is None
    assert not D.uncertain(D.confidence(13.8, tie["z_over_runner"]))
