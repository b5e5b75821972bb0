"""Recoat drops at irregular times (`diagnose.events`): found at any spacing, quiet on noise and
on a misfit that goes both ways, and named `recoat_cooling` by the diagnosis."""

import numpy as np

from jthermo.data import from_arrays, split
from jthermo.diagnose import diagnose
from jthermo.diagnose.events import detect_drops, flag_matrix, gaussian_level


def _times(rng, total, lo=35.0, hi=260.0):
    t = [float(rng.uniform(5.0, 20.0))]
    while t[-1] < total:
        t.append(t[-1] + float(rng.uniform(lo, hi)))
    return np.array(t[:-1])


def test_irregular_drops_found_where_they_are():
    """Drops at irregular, fractional times (35-260 s apart, Ts 2 s), zone 2 a sample after zone 1:
    every event found, each zone flagged at the sample whose next sample first shows its drop."""
    rng = np.random.default_rng(1)
    T, ts = 1500, 2.0
    t_ev = _times(rng, T * ts)
    first_low = np.ceil(t_ev / ts).astype(int)                     # y[k] is read at k ts
    R = 0.05 * rng.normal(size=(T, 2))
    for i, (lag, d) in enumerate([(0, 0.5), (1, 0.4)]):
        for k in first_low + lag:
            R[k:, i] -= d * np.exp(-np.arange(T - k) * ts / 400.0)
    out = detect_drops(R, ts)
    assert out["significant"] and len(out["times_s"]) == t_ev.size
    assert out["flags"][0] == (first_low - 1).tolist()
    assert out["flags"][1] == first_low.tolist()
    np.testing.assert_allclose(out["zone_drop_C"], [0.5, 0.4], atol=0.05)
    assert flag_matrix(T, out["flags"]).sum() == 2 * t_ev.size


def test_drops_quiet_on_noise_and_on_two_sided_spikes():
    """White and strongly coloured noise, one to four zones: no event. Spikes of both signs (a
    dead time's misfit at the heaters' switches), as deep as a drop: no event either (a drop
    must stand out from the record's rises)."""
    rng = np.random.default_rng(2)
    for n in (1, 2, 4):
        for k in range(5):
            T = 900
            white = 0.05 * rng.normal(size=(T, n))
            col = np.zeros((T, n))
            for t in range(1, T):
                col[t] = 0.9 * col[t - 1] + 0.03 * rng.normal(size=n)
            assert not detect_drops(white + col, 1.5)["significant"]
    R = 0.05 * rng.normal(size=(1200, 2))
    sw = np.sort(rng.choice(np.arange(20, 1180), 40, replace=False))
    for j, k in enumerate(sw):
        R[k:, :] += 0.5 * (-1) ** j * np.exp(-np.arange(1200 - k) / 20.0)[:, None]
    assert not detect_drops(R, 1.0)["significant"]
    # the Gaussian level grows with the record and the zones (more chances for noise)
    assert gaussian_level(2000, 3, 3) < gaussian_level(500, 3, 3) < gaussian_level(500, 1, 0) < 0


def _irregular_recoat_record(seed=3, T=900, ts=2.0):
    """Two first-order zones under PRBS heaters, recoat drops of 0.8 / 0.6 °C at irregular times
    35-260 s apart (never periodic), 0.04 °C noise; estimation 2/3, validation 1/3."""
    rng = np.random.default_rng(seed)
    u = np.zeros((T, 2))
    for j in range(2):
        k, s = 0, 0
        while k < T:
            h = int(rng.integers(3, 15))
            u[k:k + h, j] = 0.3 + 0.4 * s
            s, k = 1 - s, k + h
    a, B = np.array([1 / 300, 1 / 420]), np.array([[0.25, 0.04], [0.03, 0.2]])
    drop = np.zeros((T, 2))
    for t in _times(rng, T * ts):
        drop[int(t // ts), 0] += 0.8
        drop[int((t + 1.5) // ts) if (t + 1.5) // ts < T else T - 1, 1] += 0.6
    x = 25.0 + np.linalg.solve(np.diag(a), B @ np.full(2, 0.5))
    y = np.empty((T, 2))
    phi = np.exp(-a * ts)
    for k in range(T):
        y[k] = x
        x = 25.0 + phi * (x - 25.0) + (1 - phi) * (B @ u[k]) / a - drop[k]
    y = y + 0.04 * rng.normal(size=y.shape)
    d = from_arrays(u, y, ts, np.full((T, 1), 25.0), signal_names=["ambient"])
    return split(d, 2 / 3)


def test_irregular_recoat_named():
    """The diagnosis names `recoat_cooling` for drops at irregular times, with the drops found
    at their times (before, it looked only for a period: the drops do not repeat at one)."""
    est, val = _irregular_recoat_record()
    res = diagnose(est, val, mechanisms=("recoat_cooling", "heater_lag", "ambient_variation"))
    assert res["localisation"]["drops"]["used"]
    assert [f["mechanism"] for f in res["findings"]][:1] == ["recoat_cooling"]
    p = res["findings"][0]["parameters"]
    assert p["events"] >= 6 and 35.0 <= p["mean_interval_s"] <= 260.0 and p["spacing_cv"] > 0.1
    assert "not periodic" in res["findings"][0]["summary"]
    np.testing.assert_allclose(p["drop_per_zone_C"], [0.8, 0.6], rtol=0.25)
    assert res["augmented"]["mean_fit_percent"] - res["baseline"]["mean_fit_percent"] > 10.0
