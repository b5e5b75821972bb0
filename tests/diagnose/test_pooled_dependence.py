"""The slow body / drift test on pooled records (`bodydrift.records_dependence`): each record
tested on its own, with its own surroundings level, drift and body state as nuisances.

`data/pooled_drift_two_records.npz`: what the diagnosis tests on two pooled records of one
two-zone plant under an unmeasured exogenous drift (case 05 of the loop's development set,
`python experiments/diagnose_fresh_case.py --case 5`: the estimation record, 2400 samples, and
the old validation record, 1200 samples, pooled when the designed record became the validation
one): the drift fitted by `ambient_variation` and the baseline's input-driven mean temperature.
Tested on the concatenation the drift read as following the inputs ($z$ 1.64, with the
designed record's 0.76 combined 1.70: a body named at confidence 0.955); record by record it
does not.
"""

from pathlib import Path

import numpy as np

from jthermo.diagnose import bodydrift as BD

TS, STEP = 1.0, 300
LENGTHS = (3600, 3600)
DATA = Path(__file__).parent / "data" / "pooled_drift_two_records.npz"


def test_pooled_records_exogenous_drift_is_not_read_as_a_body():
    d = np.load(DATA)
    drift, drive, lengths, ts, step = d["drift"], d["drive"], tuple(d["lengths"]), float(d["ts"]), int(d["step"])
    # the concatenation's statistic (what the diagnosis used) is at the body's threshold ...
    assert BD.input_dependence(drift, drive, ts, step) >= 1.6
    zs, ok = BD.records_dependence(drift, drive, lengths, ts, step)
    # ... record by record: the first record's own statistic, the short second one untestable
    assert ok == [True, False] and zs[0] == BD.input_dependence(drift[:lengths[0]], drive[:lengths[0]], ts, step)
    # with the designed validation record's statistic, no dependence: a body is not confident
    z_designed = 0.7554150263604693
    z = BD.combined_dependence([*zs, z_designed], [*ok, True])
    assert not BD.input_dependent(z)
    assert BD.slow_order_confidence("heat_accumulation", z) < 0.95


def _records(seed):
    """Each record: a drive (the baseline's input-driven temperature) at its own mean level, and
    an exogenous smooth drift at its own level, independent of the drive."""
    rng = np.random.default_rng(seed)
    drive, drift = [], []
    for r, T in enumerate(LENGTHS):
        u = np.repeat(rng.choice([0.2, 0.6], size=T // 120), 120) + 0.3 * r
        drive.append(40.0 + 60.0 * BD.lag_filter(u, TS, 200.0))
        t = np.arange(T) * TS
        drift.append(3.0 * r + 0.8 * np.sin(2 * np.pi * t / rng.uniform(4000, 9000) + rng.uniform(0, 6.3)))
    return np.concatenate(drift), np.concatenate(drive)


def test_records_dependence_of_one_record_is_the_records_own_test():
    drift, drive = _records(5)
    a = LENGTHS[0]
    zs, ok = BD.records_dependence(drift[:a], drive[:a], (a,), TS, STEP)
    assert zs == [BD.input_dependence(drift[:a], drive[:a], TS, STEP)] and ok == [True]
    # a record too short to test is marked so (it adds nothing to the combined statistic)
    zs, ok = BD.records_dependence(drift[:a + 900], drive[:a + 900], (a, 900), TS, STEP)
    assert ok == [True, False] and zs[1] == 0.0


def test_a_body_in_every_record_stays_input_dependent():
    """A drift that is the drive through a body lag, in both records: found record by record."""
    rng = np.random.default_rng(11)
    drive, drift = [], []
    for r, T in enumerate(LENGTHS):
        u = np.repeat(rng.choice([0.1, 0.9], size=T // 600), 600)
        s = 40.0 + 60.0 * BD.lag_filter(u, TS, 200.0)
        drive.append(s)
        drift.append(5.0 * r + 0.1 * BD.lag_filter(s - s[0], TS, 1200.0) + 0.02 * rng.normal(size=T))
    zs, ok = BD.records_dependence(np.concatenate(drift), np.concatenate(drive), LENGTHS, TS, STEP)
    assert BD.input_dependent(BD.combined_dependence(zs, ok))
