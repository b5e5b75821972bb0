"""Physical plausibility of a thermal model (`validate.plausibility`): an inverse response and a
heater that cools its own sensor are flagged, a normal heater is not."""

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.signal

from jthermo.errors import ModelError
from jthermo.models import StateSpace
from jthermo.validate.plausibility import plausibility, step_responses, window


def _ss(A, B, C, ts=0.5):
    A, B, C = (jnp.asarray(np.atleast_2d(m), jnp.float64) for m in (A, B, C))
    return StateSpace(A=A, B=B, C=C, D=jnp.zeros((C.shape[0], B.shape[1])),
                      K=jnp.zeros((A.shape[0], C.shape[0])), ts=ts)


def _inverse(fast_gain=-30.0, a_fast=0.8):
    """Two first-order paths in parallel: a fast one (pole `a_fast`) of gain `fast_gain` (°C per
    unit input) and a slow one of gain 80: static gain 50, the fast one first pulls it down."""
    a_slow = 0.995
    return _ss(np.diag([a_fast, a_slow]), [[(1 - a_fast) * fast_gain], [(1 - a_slow) * 80.0]],
               [[1.0, 1.0]])


def test_step_responses_match_scipy():
    m = _inverse()
    A, B, C, D = (np.asarray(x) for x in (m.A, m.B, m.C, m.D))
    _, (ref,) = scipy.signal.dstep((A, B, C, D, 0.5), n=200)
    np.testing.assert_allclose(step_responses(A, B, C, D, 200)[:, 0, 0], ref[:, 0], rtol=1e-12)
    assert window(A, 1) == int(np.ceil(5.0 / -np.log(0.995)))


def test_inverse_response_is_flagged_and_a_normal_heater_is_not():
    bad = plausibility(_inverse(), noise_std=0.3, input_names=["heater"], output_names=["T"])
    (p,) = bad["pairs"]
    assert bad["stable"] and p["dc_gain"] == pytest.approx(50.0, rel=1e-9)
    # the fast path's -30 °C is reached early, before the slow one has risen much
    assert p["inverse_response"] and 10.0 < p["wrong_way_C"] < 30.0 and p["wrong_way_at_s"] < 10
    assert not p["cools_own_sensor"]
    assert len(bad["warnings"]) == 1 and bad["warnings"][0].startswith("heater -> T:")
    assert "inverse response" in bad["warnings"][0]
    # the same model with both paths heating: monotone, nothing to say
    good = plausibility(_inverse(fast_gain=+30.0), noise_std=0.3)
    assert good["warnings"] == [] and not good["pairs"][0]["inverse_response"]
    assert good["pairs"][0]["wrong_way_C"] == 0.0
    # a dip below the noise level is not a finding: the threshold follows the noise
    # (fast path -4 °C, pole 0.5: a 2.3 °C dip; threshold max(3 sigma, 1 % of 76 °C))
    small = plausibility(_inverse(fast_gain=-4.0, a_fast=0.5), noise_std=1.0)
    assert small["warnings"] == [] and 2.0 < small["pairs"][0]["wrong_way_C"] < 2.5
    assert plausibility(_inverse(fast_gain=-4.0, a_fast=0.5), noise_std=0.1)["pairs"][0]["inverse_response"]


def test_heater_cooling_its_own_sensor_and_unstable_model():
    # two zones: heater 1 cools sensor 1 (wrong), heater 2 heats both (right)
    m = _ss(np.diag([0.9, 0.95]), [[-1.0, 0.5], [0.0, 1.0]], np.eye(2))
    out = plausibility(m, noise_std=[0.1, 0.1], input_span=0.5)
    flags = {(p["output"], p["input"]): (p["cools_own_sensor"], p["inverse_response"])
             for p in out["pairs"]}
    assert flags == {("y1", "u1"): (True, False), ("y1", "u2"): (False, False),
                     ("y2", "u1"): (False, False), ("y2", "u2"): (False, False)}
    assert [w.split(":")[0] for w in out["warnings"]] == ["u1 -> y1"]
    assert "cools its own sensor" in out["warnings"][0]
    assert out["pairs"][0]["dc_gain"] == pytest.approx(-10.0, rel=1e-9)   # per unit input
    unstable = plausibility(_ss([[1.01]], [[0.1]], [[1.0]]))
    assert not unstable["stable"] and "not stable" in unstable["warnings"][0]
    with pytest.raises(ModelError, match="noise_std must be >= 0"):
        plausibility(m, noise_std=-1.0)


@pytest.mark.parametrize("fast_gain", [-30.0, 30.0])
def test_cli_fit_reports_implausible_models_as_warnings(tmp_path, capsys, fast_gain):
    """`jthermo fit --physics none` on a record of an inverse-response heater: exit 0, the model
    is written, and the finding is in the text (stderr) and in the JSON `warnings`; none for a
    normal one. Under the default (`--physics heat`) the given orders' implausible model is
    refused with the finding, nothing written."""
    import json

    from jthermo import cli
    from jthermo.data import from_arrays, save_csv

    m = _inverse(fast_gain)
    rng = np.random.default_rng(0)
    u = np.repeat(rng.integers(0, 2, 40), 50)[:, None].astype(np.float64)   # 2000 samples
    y = np.asarray(m.simulate(jnp.asarray(u))) + 25.0 + 0.01 * rng.standard_normal((2000, 1))
    save_csv(from_arrays(u, y, ts=0.5, input_names=["heater"], output_names=["T"]),
             tmp_path / "d.csv")
    js = tmp_path / "fit.json"
    argv = ["fit", str(tmp_path / "d.csv"), "--model", "arx", "--orders", "2,2,1",
            "--out", str(tmp_path / "m.jtm"), "--json", str(js), "--quiet"]
    if fast_gain < 0:
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert "not a plant heat could be" in err and "heater -> T" in err
        assert not (tmp_path / "m.jtm").exists() and not js.exists()
    assert cli.main(argv + ["--physics", "none"]) == 0
    rep = json.loads(js.read_text())
    err = capsys.readouterr().err
    assert (tmp_path / "m.jtm").exists() and rep["mean_fit_percent"] > 95
    if fast_gain < 0:
        assert len(rep["warnings"]) == 1 and "heater -> T" in rep["warnings"][0]
        assert err.strip() == f"warning: {rep['warnings'][0]}"
    else:
        assert rep["warnings"] == [] and err == ""
