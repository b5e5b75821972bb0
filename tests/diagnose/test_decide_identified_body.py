"""A stored-heat body slower than the record yields to a tied, identified one-parameter rival."""

from jthermo.diagnose import decide as D

ROWS = [{"mechanism": "heat_accumulation", "parameters": {"time_constant_s": 1.06e6}},
        {"mechanism": "radiative_loss", "parameters": {"share_of_loss": 0.29}},
        {"mechanism": "input_nonlinearity", "parameters": {"exponent": 0.97}}]
N_PARAMS = {"heat_accumulation": 4, "radiative_loss": 1, "input_nonlinearity": 1}.get


def names(rows):
    return [r["mechanism"] for r in rows]


def test_unidentified_body_yields_to_tied_rival():
    out = D.prefer_identified(ROWS, 3600.0, lambda r: True, N_PARAMS)
    assert names(out) == ["radiative_loss", "heat_accumulation", "input_nonlinearity"]
    # only a rival the top does not beat
    out = D.prefer_identified(ROWS, 3600.0, lambda r: r["mechanism"] == "input_nonlinearity", N_PARAMS)
    assert names(out) == ["input_nonlinearity", "heat_accumulation", "radiative_loss"]


def test_identified_body_or_no_tie_keeps_order():
    body = [{**ROWS[0], "parameters": {"time_constant_s": 1800.0}}] + ROWS[1:]
    assert names(D.prefer_identified(body, 3600.0, lambda r: True, N_PARAMS)) == names(body)
    assert names(D.prefer_identified(ROWS, 3600.0, lambda r: False, N_PARAMS)) == names(ROWS)
    assert names(D.prefer_identified(ROWS[1:], 3600.0, lambda r: True, N_PARAMS)) == names(ROWS[1:])
    # the limit is two records: 7200 s on a one-hour record is still identified
    assert D.body_identified(7200.0, 3600.0) and not D.body_identified(7201.0, 3600.0)


def test_an_unidentified_body_is_not_moved_ahead_by_its_estimation_evidence():
    # a loss named first by validation; a 5 h body on a 40 min record, tied with it and stronger
    # on the estimation record (set 19's case 17): evidence alone would name the body
    rows = [{"mechanism": "radiative_loss", "estimation_lr": 3221.7, "parameters": {}},
            {"mechanism": "heat_accumulation", "estimation_lr": 3265.7,
             "parameters": {"time_constant_s": 19198.7}}]
    dof = {"radiative_loss": 1, "heat_accumulation": 2}.get
    ev = lambda tied: names(D.prefer_evidence(rows, tied, lambda r: dof(r["mechanism"])))
    assert ev(lambda r: True) == ["heat_accumulation", "radiative_loss"]
    assert ev(lambda r: D.promotable(r, 2400.0)) == ["radiative_loss", "heat_accumulation"]
    # a body the record identifies (or any other mechanism) may still be moved ahead
    assert D.promotable({**rows[1], "parameters": {"time_constant_s": 1800.0}}, 2400.0)
    assert D.promotable(rows[0], 2400.0)
    assert not D.promotable({"mechanism": "heat_accumulation", "parameters": {}}, 2400.0)
