"""One-zone records, fractional dead time, slow body vs drift, the decision's null
behaviour, actuator flags, and real recordings that must not crash."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo import printer as P
from jthermo.data import from_arrays, load, split
from jthermo.diagnose import decide as D
from jthermo.diagnose import diagnose
from jthermo.diagnose import mechanisms as M
from jthermo.inputs import prbs

REAL = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "real"
SUB = 4


def _printer_record(zones, effects, seed, duration=1500.0, noise=0.05):
    """Printer at Ts/4 (any dead time a multiple of 0.25 s), every 4th sample kept, PRBS."""
    pr = P.make_printer(zones, effects=effects, seed=seed, ts=1.0 / SUB)
    rng = np.random.default_rng(seed)
    T = int(duration)
    u = np.asarray(prbs(seed, T, pr.n_inputs, hold=(3, 15)), float)
    y, _ = P.simulate_open_loop(pr, np.repeat(u, SUB, axis=0), None, P.steady_state(pr, 0.5))
    y = np.asarray(y)[::SUB] + noise * rng.normal(size=(T, pr.n_outputs))
    d = from_arrays(u, y, 1.0, np.full((T, 1), float(pr.surroundings)), signal_names=["ambient"])
    return split(d, 2 / 3)


def test_fractional_delay_input_interpolates():
    lay = M.make_layout(1, 1, 2)
    u = jnp.asarray(np.r_[np.zeros(5), np.ones(10)][:, None])
    th = jnp.zeros(lay.size)
    on = jnp.asarray(M.on_vector(["input_delay"]))
    got, _ = M.delayed_inputs(th, on, u, jnp.zeros(1), 2.5, lay)          # d = 2.5 samples (dfrac 0)
    np.testing.assert_allclose(np.asarray(got[:, 0])[5:10], [0, 0, 0.5, 1, 1])


def test_one_zone_record_is_diagnosed_and_fractional_delay_named():
    est, val = _printer_record(1, {"input_delay": {"delay_s": 2.5}}, 3)
    res = diagnose(est, val)
    assert all(c["mechanism"] != "lateral_conduction" for c in res["candidates"])
    assert res["findings"] and res["findings"][0]["mechanism"] == "input_delay"
    assert abs(res["findings"][0]["parameters"]["delay_s"] - 2.5) <= 0.5
    assert res["augmented"]["mean_fit_percent"] >= res["baseline"]["mean_fit_percent"]


def test_null_one_zone_record_stays_quiet():
    est, val = _printer_record(1, {}, 8, noise=0.08)
    res = diagnose(est, val)
    assert res["verdict"] == "no_significant_mismatch"
    assert res["decision"]["family_false_alarm_rate"] == D.ALPHA


def test_inputs_constant_in_both_records_are_left_out():
    from jthermo.diagnose.checks import drop_idle_inputs

    rng = np.random.default_rng(0)
    u = np.c_[rng.random(100), np.zeros(100)]
    d = from_arrays(u, rng.random((100, 2)), 1.0)
    e, v, dropped = drop_idle_inputs(d, d)
    assert dropped == ["2"] and e.n_inputs == 1 and v.input_names == ("1",)
    u2 = u.copy()
    u2[50:, 1] = 0.5                     # used in one record: kept
    assert drop_idle_inputs(d, d.replace(u=u2))[2] == []


def test_predictive_test_false_alarm_rate_on_noise():
    """Two equally good predictions of coloured noise: the one-sided test rejects about as
    often as its level says (z is close to standard normal under the null)."""
    rng = np.random.default_rng(0)
    zs = []
    for _ in range(200):
        w = rng.normal(size=(1800, 2))
        e = np.zeros_like(w)
        for k in range(1, 1800):
            e[k] = 0.9 * e[k - 1] + w[k]
        zs.append(D.predictive_z(e + 0.01 * rng.normal(size=e.shape), e + 0.01 * rng.normal(size=e.shape)))
    zs = np.asarray(zs)
    assert abs(np.mean(zs)) < 0.3 and 0.6 < np.std(zs) < 1.5
    assert np.mean(zs > D.thresholds(1, 1)[0]) <= 0.03


def test_actuator_flags_a_contradicting_finding():
    est, val = _printer_record(1, {"input_nonlinearity": {"exponent": 1.6}}, 5)
    res = diagnose(est, val, actuator="resistive-pwm")
    assert all(f["mechanism"] != "input_nonlinearity" for f in res["findings"])
    assert any(f["mechanism"] == "input_nonlinearity" for f in res["flagged"])


@pytest.mark.slow
def test_slow_body_is_not_called_drift():
    est, val = _printer_record(2, {"heat_accumulation": {"time_constant_s": 1800.0, "share": 0.5}}, 11,
                               duration=5400.0)
    res = diagnose(est, val)
    assert res["findings"][0]["mechanism"] == "heat_accumulation"


def _real_pairs():
    pairs = []
    k = REAL / "klipper_onionheater"
    pairs.append((k / "heattest_200", k / "heattest_fan_200"))
    c = REAL / "tclab_cace2020"
    pairs.append((c / "id_2heaters", c / "val_2heaters"))
    return pairs


@pytest.mark.slow
@pytest.mark.skipif(not REAL.is_dir(), reason="real recordings not present")
@pytest.mark.parametrize("pair", _real_pairs(), ids=["klipper", "tclab_cace"])
def test_real_recordings_do_not_crash(pair):
    jax.clear_caches()
    est, val = (load(p / "data.csv") for p in pair)
    # a short piece of each run keeps the test fast; the whole runs are in diagnose_real.py
    est = est.replace(u=est.u[:400], y=est.y[:400], w=None if est.w is None else est.w[:400])
    val = val.replace(u=val.u[:300], y=val.y[:300], w=None if val.w is None else val.w[:300])
    res = diagnose(est, val)
    assert res["verdict"] in ("mismatch", "no_significant_mismatch")
    assert np.isfinite(res["baseline"]["mean_fit_percent"])


def test_no_candidate_left_is_a_one_line_error():
    from jthermo.errors import ConfigError

    rng = np.random.default_rng(0)
    rec = [from_arrays(rng.uniform(0, 1, (120, 1)), 30 + rng.normal(0, 0.1, (120, 1)))
           for _ in range(2)]
    for mechanisms in ((), ("lateral_conduction",)):   # a one-zone record has no neighbour
        with pytest.raises(ConfigError, match="no candidate mechanism"):
            diagnose(*rec, mechanisms=mechanisms)
