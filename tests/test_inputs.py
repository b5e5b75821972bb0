import jax
import numpy as np
import pytest
import scipy.signal

from jthermo.errors import DataError
from jthermo.inputs import crest_factor, hold_from_band, periodogram, prbs


def _runs(col):
    """Lengths of the constant runs of a 1-D signal."""
    change = np.flatnonzero(np.diff(col) != 0) + 1
    edges = np.concatenate([[0], change, [len(col)]])
    return np.diff(edges)


def test_prbs_levels_shape_and_crest():
    u = np.asarray(prbs(0, 1200, 2, levels=(0.2, 0.9)))
    assert u.shape == (1200, 2)
    assert set(np.unique(u)) == {0.2, 0.9}
    np.testing.assert_allclose(np.asarray(crest_factor(u)), 1.0, rtol=1e-12)
    np.testing.assert_allclose(float(crest_factor(u[:, 0], centre=0.55)), 1.0, rtol=1e-12)


def test_prbs_deterministic_and_independent(getkey):
    a = np.asarray(prbs(7, 1200, 2))
    b = np.asarray(prbs(7, 1200, 2))
    c = np.asarray(prbs(8, 1200, 2))
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)
    assert np.any(a[:, 0] != a[:, 1])              # channels are generated independently
    k = getkey()
    np.testing.assert_array_equal(np.asarray(prbs(k, 1200, 2)), np.asarray(prbs(k, 1200, 2)))
    # channel correlation is small: independent signals
    d = a - a.mean(0)
    rho = (d[:, 0] @ d[:, 1]) / np.sqrt((d[:, 0] @ d[:, 0]) * (d[:, 1] @ d[:, 1]))
    assert abs(rho) < 5 / np.sqrt(1200 / 9)           # ~5 sigma with ~9-sample holds


@pytest.mark.parametrize("hold", [(3, 15), (2, 2), (5, 40)])
def test_prbs_hold_lengths(hold):
    u = np.asarray(prbs(3, 1200, 2, hold=hold))
    for j in range(2):
        runs = _runs(u[:, j])[:-1]                 # the last run is cut by the record's end
        assert runs.min() >= hold[0] and runs.max() <= hold[1]


def test_prbs_band_maps_to_holds():
    assert hold_from_band((0.01, 0.1), ts=1.0) == (5, 50)
    assert hold_from_band((0.02, 0.5), ts=1.0) == (1, 25)
    u = np.asarray(prbs(1, 1200, 2, band=(0.01, 0.1)))
    runs = _runs(u[:, 0])[:-1]
    assert runs.min() >= 5 and runs.max() <= 50
    # the power lies mostly at and below the band's top
    f, p = periodogram(u[:, 0], 1.0)
    f, p = np.asarray(f), np.asarray(p)
    assert p[f <= 0.1].sum() > 0.85 * p.sum()


@pytest.mark.parametrize("kwargs, match", [
    ({"levels": (0.7, 0.3)}, "low < high"),
    ({"levels": (0.5, 0.5)}, "low < high"),
    ({"levels": (0.1, float("nan"))}, "finite"),
    ({"levels": (0.1,)}, "pair"),
    ({"band": (0.2, 0.1)}, "f_lo < f_hi"),
    ({"band": (0.01, 0.8)}, "Nyquist"),
    ({"band": (0.0, 0.1)}, "0 < f_lo"),
    ({"band": (0.01, 0.1), "hold": (2, 5)}, "not both"),
    ({"hold": (5, 2)}, "min <= max"),
    ({"hold": (0, 2)}, "min <= max"),
    ({"ts": 0.0}, "positive"),
])
def test_prbs_bad_arguments(kwargs, match):
    with pytest.raises(DataError, match=match):
        prbs(0, 100, 2, **kwargs)


def test_prbs_bad_sizes_and_key():
    with pytest.raises(DataError, match="n_samples"):
        prbs(0, 0, 2)
    with pytest.raises(DataError, match="n_channels"):
        prbs(0, 10, 0)
    with pytest.raises(DataError, match="seed"):
        prbs(-1, 10, 1)
    with pytest.raises(DataError, match="key"):
        prbs("abc", 10, 1)
    with pytest.raises(DataError, match="single key"):
        prbs(jax.random.split(jax.random.key(0), 2), 10, 1)


def test_crest_factor_of_sine_and_errors():
    t = np.arange(4000)
    s = np.sin(2 * np.pi * t / 40)
    np.testing.assert_allclose(float(crest_factor(s, centre=0.0)), np.sqrt(2), rtol=1e-3)
    with pytest.raises(DataError, match="no power"):
        crest_factor(np.ones(10))
    with pytest.raises(DataError, match="signal"):
        crest_factor(np.ones((2, 2, 2)))


@pytest.mark.parametrize("n", [256, 255])
def test_periodogram_matches_scipy(n):
    x = np.random.default_rng(0).standard_normal((n, 2)) + 3.0
    f, p = periodogram(x, ts=2.0)
    fs, ps = scipy.signal.periodogram(x, fs=0.5, axis=0)
    np.testing.assert_allclose(np.asarray(f), fs, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(p), ps, rtol=1e-10, atol=1e-12)
    with pytest.raises(DataError, match="signal"):
        periodogram(np.ones(1))
