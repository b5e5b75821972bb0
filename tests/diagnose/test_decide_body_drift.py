"""A stored-heat body is told from an exogenous drift by its input dependence."""

import numpy as np

from jthermo.diagnose import bodydrift as BD
from jthermo.diagnose import decide as D

TS, T, STEP = 1.0, 3600, 300


def _drive(rng):
    """Input-driven temperature: a PRBS around a level that steps every ~15 min, through a zone."""
    level = rng.uniform(0.0, 0.3, 5)[np.minimum(np.arange(T) // 900, 4)]
    u = level + 0.3 * (rng.random(T // 10).repeat(10) < 0.5)
    return 40.0 + BD.lag_filter(60.0 * u, TS, 300.0)


def test_lag_filter_is_a_unit_gain_first_order_lag():
    z = BD.lag_filter(np.ones(4000), 2.0, 100.0)
    assert z[0] == 0.0
    np.testing.assert_allclose(z[1:4], 1 - np.exp(-2.0 * np.arange(1, 4) / 100.0))
    assert abs(z[-1] - 1.0) < 1e-12


def _dependence_z(seed: int, trials: int, slow) -> np.ndarray:
    """`bodydrift.input_dependence` of `slow(rng, t, s)` plus sensor noise (0.05 °C) against the
    drive `s`, for `trials` drives drawn in turn from `default_rng(seed)`."""
    rng = np.random.default_rng(seed)
    t = np.arange(T) * TS
    z = []
    for _ in range(trials):
        s = _drive(rng)
        z.append(BD.input_dependence(slow(rng, t, s) + 0.05 * rng.normal(size=T), s, TS, STEP))
    return np.asarray(z)


def test_exogenous_drift_is_not_input_dependent():
    """Null: ramps and slow sinusoids unrelated to the drive reach the 5 % level rarely."""
    def drift(rng, t, s):
        return rng.uniform(1.5, 4.0) * (0.5 * (t / t[-1] - 0.5)
                                        + 0.5 * np.sin(2 * np.pi * t / rng.uniform(2400, 7200)
                                                       + rng.uniform(0, 6.3)))

    assert np.mean(_dependence_z(1, 30, drift) >= 1.645) <= 0.1


def test_body_driven_by_the_inputs_is_input_dependent():
    """A warming body (lag of the drive plus its initial state's decay) is found most times."""
    def body(rng, t, s):
        tau = rng.uniform(1200.0, 3600.0)
        return 0.4 * (BD.lag_filter(s - s[0], TS, tau) - rng.uniform(0.0, 10.0) * np.exp(-t / tau))

    assert np.mean(_dependence_z(2, 10, body) >= 1.645) >= 0.5
    assert BD.input_dependence(np.zeros(50), np.ones(50), TS, STEP) == 0.0    # too short: no test


def test_body_goes_ahead_of_drift_only_when_input_dependent():
    rows = [{"mechanism": m} for m in ("ambient_variation", "radiative_loss", "heat_accumulation")]
    names = lambda rs: [r["mechanism"] for r in rs]
    assert names(BD.order_body_drift(rows, 1.96)) == ["heat_accumulation", "ambient_variation",
                                                     "radiative_loss"]
    assert names(BD.order_body_drift(rows, 1.0)) == names(rows)
    assert names(BD.order_body_drift(rows[:2], 5.0)) == names(rows[:2])
    body_first = [{"mechanism": m} for m in ("heat_accumulation", "ambient_variation")]
    assert names(BD.order_body_drift(body_first, 0.5)) == names(body_first)


def test_body_and_drift_tie_without_input_dependence():
    both = ["heat_accumulation", "ambient_variation"]
    assert BD.body_drift_tied(both, 0.0)
    assert not BD.body_drift_tied(both, 1.7)                 # above the one-sided 5 % level
    assert not BD.body_drift_tied(["heat_accumulation", "heater_lag"], 0.0)


def test_uncertain_below_the_rival_level():
    """A confidence under 1 - RIVAL_LEVEL is uncertain; the summary then says so and names rivals."""
    from jthermo.diagnose.describe import summary

    assert D.CONFIDENT == 1.0 - D.RIVAL_LEVEL
    assert D.uncertain(0.94) and not D.uncertain(0.95) and not D.uncertain(0.999)
    assert D.uncertain(D.confidence(3.0, 1.0))             # beats the baseline, not the runner-up
    assert not D.uncertain(D.confidence(5.0, None))
    # better than the runner-up on the validation record, tied with it on the estimation record
    assert D.uncertain(D.confidence(9.3, 4.77, 0.12))
    assert D.confidence(9.3, 4.77, 0.12) == D.confidence(9.3, 0.12)
    assert not D.uncertain(D.confidence(9.3, 4.77, 3.0))
    assert D.confidence(9.3, 4.77, float("nan")) == D.confidence(9.3, 4.77)
    line = summary("ambient_variation", [1], {}, True, ["heat_accumulation"])
    assert line.startswith("Uncertain (the data do not separate it from heat_accumulation)")
    assert summary("ambient_variation", [1], {}, True).startswith("Uncertain (its confidence is below 0.95)")
    assert not summary("ambient_variation", [1], {}).startswith("Uncertain")


def test_slow_rival_and_its_confidence_come_from_input_dependence():
    body, drift = "heat_accumulation", "ambient_variation"
    # the other slow explanation must improve the estimation record to be a rival
    assert not BD.slow_rival(drift, False, 0.0) and not BD.slow_rival("heater_lag", True, 0.0)
    assert BD.slow_rival(drift, True, 0.0) and BD.slow_rival(body, True, 0.0)
    # input dependence decides for a body named first, never for a drift named first
    assert not BD.slow_rival(body, True, 2.0) and BD.slow_rival(drift, True, 2.0)
    # no evidence either way: even odds; the two confidences are complementary
    assert BD.slow_order_confidence(body, 0.0) == BD.slow_order_confidence(drift, 0.0) == 0.5
    for z in (-1.0, 0.7, 2.5):
        assert abs(BD.slow_order_confidence(body, z) + BD.slow_order_confidence(drift, z) - 1.0) < 1e-12
    assert D.uncertain(BD.slow_order_confidence(body, 1.0)) and not D.uncertain(BD.slow_order_confidence(body, 2.0))
    assert D.uncertain(BD.slow_order_confidence(drift, -1.0))
    assert BD.slow_order_confidence(body, float("nan")) == 0.5


def test_common_drift_needs_the_zones_to_agree():
    """One surroundings signal: the zones' own drifts agree (noisy copies pass); opposite or
    unrelated drifts, or too few knots to tell, do not."""
    rng = np.random.default_rng(3)
    k = np.linspace(0.0, 1.0, 13)
    d = 2.0 * (0.5 * (k - 0.5) + 0.5 * np.sin(2 * np.pi * k / 0.8 + 1.0))
    same = np.stack([d + 0.1 * rng.normal(size=k.size) for _ in range(3)])
    assert D.common_drift(D.common_drift_z(same))
    assert not D.common_drift(D.common_drift_z(np.stack([d, -d])))
    unrelated = [D.common_drift_z(rng.normal(size=(2, k.size))) for _ in range(200)]
    assert np.mean([D.common_drift(z) for z in unrelated]) <= 0.1      # about the 5 % level
    assert D.common_drift_z(same[:, :3]) == 0.0 and D.common_drift_z(same[:1]) == 0.0


def test_a_record_too_short_to_test_adds_nothing_and_two_records_combine():
    """Knots every 300 s: 2400 s give the 8 points the test needs, 2100 s do not (and return 0);
    an untestable record leaves the other's statistic as it is, two testable ones combine as
    Stouffer's sum over the square root of their number."""
    assert BD.dependence_testable(2400, STEP) and not BD.dependence_testable(2100, STEP)
    rng = np.random.default_rng(2)
    s = _drive(rng)
    body = 2.0 * BD.lag_filter(s - s[0], TS, 1200.0) / 60.0
    assert BD.input_dependence(body[:2100], s[:2100], TS, STEP) == 0.0
    z_long = BD.input_dependence(body, s, TS, STEP)
    assert BD.input_dependent(z_long)
    # a short (estimation) record and a long (designed validation) one: the long one decides
    assert BD.combined_dependence([0.0, z_long], [False, True]) == z_long
    assert BD.combined_dependence([z_long, 0.0], [True, False]) == z_long
    assert np.isclose(BD.combined_dependence([1.0, 1.5], [True, True]), 2.5 / np.sqrt(2.0))
    assert BD.combined_dependence([1.0, 2.0], [False, False]) == 0.0
    # p = 1 on one record (-inf alone) counts as the rank test's largest magnitude
    assert np.isclose(BD.combined_dependence([-np.inf, 1.96], [True, True]), 0.0, atol=1e-2)


def test_a_slow_top_is_not_measured_against_the_other_slow_explanation():
    """Set 14 case 04 (a slow body, the body ordered first by the drift's input dependence) was
    reported at confidence 5e-77: its runner-up on the validation record was the drift, which
    re-estimates its knots there. The runner-up of a slow top skips the other slow explanation
    (unmeasured surroundings only); any other top keeps the best other candidate."""
    body, drift = "heat_accumulation", "ambient_variation"
    assert BD.confidence_runner(body, [drift, "heater_lag"], False) == 1
    assert BD.confidence_runner(drift, [body], False) is None
    assert BD.confidence_runner(body, [drift, "heater_lag"], True) == 0      # measured: as before
    assert BD.confidence_runner("heater_lag", [drift, body], False) == 0
    assert BD.confidence_runner(body, [], False) is None
