"""A finding's effect is read against the sensor noise (`decide.sensor_noise`)."""

import numpy as np

from jthermo.diagnose import decide as D
from jthermo.diagnose.describe import summary


def test_sensor_noise_reads_the_white_noise_beside_a_smooth_model_error():
    """White noise of 0.1 °C beside a slow model error of 2 °C amplitude: the estimate is the
    noise (within 3 %), not the residual's RMS (about 1.4 °C)."""
    rng = np.random.default_rng(0)
    t = np.arange(5000)[:, None]
    e = 2.0 * np.sin(2 * np.pi * t / 1500.0 + np.array([0.0, 1.0])) + 0.1 * rng.normal(size=(5000, 2))
    assert abs(D.sensor_noise(e) - 0.1) < 0.003
    assert D.rms(e) > 1.0
    assert np.isnan(D.rms(np.array([1.0, np.nan])))


def test_an_effect_below_the_noise_is_said_so():
    assert D.below_noise(0.02, 0.05) and not D.below_noise(0.08, 0.05)
    assert not D.below_noise(float("nan"), 0.05)
    line = summary("ambient_variation", [1, 2], {"range_C": 0.07}, small=(0.02, 0.05))
    assert line.startswith("Small effect (0.02 °C RMS on the prediction, below the sensor noise 0.05 °C)")
    assert not summary("ambient_variation", [1, 2], {"range_C": 0.07}).startswith("Small")
