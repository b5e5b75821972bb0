"""`decide.prefer_evidence`: of the candidates tied with the top on the validation record, the one
with the strongest estimation evidence is named."""

from jthermo.diagnose import decide as D

# held-out set 7 case 02 (natural convection, one zone): the drift's validation MSE is lowest, the
# radiative loss has the strongest estimation evidence for its one parameter
ROWS = [{"mechanism": "ambient_variation", "estimation_lr": 678.7},
        {"mechanism": "heat_accumulation", "estimation_lr": 650.9},
        {"mechanism": "radiative_loss", "estimation_lr": 668.7}]
DOF = {"ambient_variation": 9, "heat_accumulation": 4, "radiative_loss": 1, "input_nonlinearity": 1}
dof = lambda r: DOF[r["mechanism"]]
names = lambda rows: [r["mechanism"] for r in rows]


def test_strongest_evidence_among_tied_is_named():
    out = D.prefer_evidence(ROWS, lambda r: True, dof)
    assert names(out) == ["radiative_loss", "ambient_variation", "heat_accumulation"]


def test_a_candidate_the_top_beats_is_not_moved():
    out = D.prefer_evidence(ROWS, lambda r: r["mechanism"] != "radiative_loss", dof)
    assert names(out) == names(ROWS)


def test_slow_pair_keeps_its_own_order():
    # the body has the stronger evidence but the drift was ranked first by their own test: kept
    rows = [{"mechanism": "ambient_variation", "estimation_lr": 100.0},
            {"mechanism": "heat_accumulation", "estimation_lr": 400.0}]
    assert names(D.prefer_evidence(rows, lambda r: True, dof)) == names(rows)
    # a non-slow top may yield to the first slow candidate, never to the second
    rows = [{"mechanism": "input_nonlinearity", "estimation_lr": 50.0},
            {"mechanism": "ambient_variation", "estimation_lr": 60.0},
            {"mechanism": "heat_accumulation", "estimation_lr": 400.0}]
    assert names(D.prefer_evidence(rows, lambda r: True, dof))[0] == "input_nonlinearity"


def test_equal_evidence_keeps_the_validation_order():
    rows = [{"mechanism": "input_nonlinearity", "estimation_lr": 30.0},
            {"mechanism": "radiative_loss", "estimation_lr": 30.0}]
    assert names(D.prefer_evidence(rows, lambda r: True, dof)) == names(rows)
    assert D.prefer_evidence(rows[:1], lambda r: True, dof) == rows[:1]


def test_evidence_beyond_scipy_underflow_still_ranks():
    # held-out set 20 case 36 (natural convection, 4 zones): both tied candidates' ratios are far
    # above the ~1400 where `chi2.logsf` underflows to -inf; the stronger one (radiation) is named
    rows = [{"mechanism": "input_nonlinearity", "estimation_lr": 4454.0},
            {"mechanism": "radiative_loss", "estimation_lr": 4654.0}]
    d4 = lambda r: 4
    assert names(D.prefer_evidence(rows, lambda r: True, d4)) == ["radiative_loss", "input_nonlinearity"]
    assert D.chi2_log_tail(4654.0, 4) < D.chi2_log_tail(4454.0, 4) < D.chi2_log_tail(1000.0, 4) < 0.0


def test_chi2_log_tail_matches_scipy_where_finite():
    from scipy.stats import chi2

    for k in (1, 4, 9, 40):
        for x in (5.0, 300.0, 1300.0):
            assert abs(D.chi2_log_tail(x, k) - chi2.logsf(x, k)) < 1e-9 * max(1.0, abs(chi2.logsf(x, k)))
    # and continues it smoothly past the underflow (the asymptotic series against the last finite value)
    assert abs(D.chi2_log_tail(1400.0, 4) - chi2.logsf(1400.0, 4)) < 1e-6
    assert D.chi2_log_tail(1500.0, 4) < D.chi2_log_tail(1400.0, 4)
