"""Periodic drops in coloured residuals (hard set 6 case 10: a 185.48 s sweep over three
zones at Ts 0.45 s, found at the right period with statistic 6.08 < 7 on plain differences,
9.58 prewhitened; its validation record, 2.9 periods long, got every phase 0)."""

import numpy as np

from jthermo.diagnose.localise import PERIOD_THRESHOLD, detect_periodic, prewhitened_differences


def _ar_residual(T, n, phi, rng):
    w = rng.normal(size=(T, n))
    x = np.zeros((T, n))
    for k in range(1, T):
        x[k] = phi * x[k - 1] + w[k]
    return x


def test_prewhitened_differences_align_and_whiten():
    rng = np.random.default_rng(0)
    D = np.diff(_ar_residual(3000, 2, 0.9, rng), axis=0)
    W = prewhitened_differences(D)
    assert W.shape == D.shape
    # the differenced AR(1) is negatively correlated at lag 1; whitened it is not
    r1 = lambda x: float(np.corrcoef(x[1:], x[:-1])[0, 1])
    assert r1(D[:, 0]) < -0.03
    assert abs(r1(W[10:, 0])) < 0.05
    # a spike keeps its place
    D2 = D.copy()
    D2[1500, :] -= 40.0
    assert int(np.argmin(prewhitened_differences(D2)[:, 0])) == 1500


def test_drops_in_coloured_noise_are_found_and_noise_alone_is_not():
    rng = np.random.default_rng(1)
    T, ts, P = 2400, 0.45, 185.48 / 0.45
    R = 0.15 * _ar_residual(T, 3, 0.9, rng)
    null = detect_periodic(R, ts)
    assert not null["significant"]
    # drops of 1 °C sweeping the zones, each followed by the slow recovery a baseline leaves
    for i in range(3):
        for m in range(6):
            k = int(P * (m + 0.5)) + i
            if k < T:
                R[k:, i] -= 1.0 * np.exp(-np.arange(T - k) * ts / 120.0)
    found = detect_periodic(R, ts)
    assert found["significant"] and found["statistic"] > PERIOD_THRESHOLD
    assert abs(found["period_s"] - 185.48) < 1.0


def test_a_given_period_gets_phases_on_a_record_shorter_than_four_periods():
    rng = np.random.default_rng(2)
    T, ts, P = 1200, 0.45, 185.48 / 0.45          # 2.9 periods
    R = 0.05 * rng.normal(size=(T, 1))
    for m in range(3):
        k = int(P * m + 100)
        if k < T:
            R[k:, 0] -= 1.0
    out = detect_periodic(R, ts, period_range=(P * ts, P * ts))
    assert abs(out["zone_phase"][0] - 101) <= 2
