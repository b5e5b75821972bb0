"""`jthermo tune`'s defaults on the virtual printer: 60 Adam steps at the library's learning
rate with float32 training rollouts for pi, 30 steps at 0.1 in float64 for lqg
(`cli.control.SHORT_STEPS`, `SHORT_LR`, `TRAIN_DTYPE`); an explicit `--steps` keeps the
library's learning rate. From `MANY_ZONES` zones lqg_ff takes `MANY_ZONES_STEPS` at
`MANY_ZONES_LR`; at 1 zone and 4 the defaults are those of any other N below it."""

import json

import pytest

from jthermo import cli
from jthermo.cli.control import SHORT_LR, SHORT_STEPS, TRAIN_DTYPE


@pytest.mark.parametrize("family, argv, steps, lr, dtype", [
    ("pi", [], 60, None, "float32"),
    ("lqg", [], 30, 0.1, None),
    ("lqg", ["--steps", "60"], 60, None, None),
    ("lqg_ff", [], 150, None, None),
    ("lqg_ff", ["--zones", "1"], 150, None, None),
    ("lqg_ff", ["--zones", "8"], 150, None, None),
    ("lqg_ff", ["--zones", "16"], 60, 0.1, None),
    ("lqg_ff", ["--zones", "16", "--steps", "150"], 150, None, None),
    ("pi", ["--zones", "16"], 60, None, "float32"),
])
def test_tune_defaults_per_family(family, argv, steps, lr, dtype, tmp_path, monkeypatch, capsys):
    from jthermo import tune

    seen = {}

    def fake_tune_report(fam, **kw):
        seen.update(kw)
        return {"controller": fam, "start_cost": 2.0, "tuned_cost": 1.0, "lambda_pi_cost": 2.0,
                "improvement_percent": 50.0, "scenarios": {}, "history": [2.0], "seconds": 0.1}

    monkeypatch.setattr(tune, "tune_report", fake_tune_report)
    js = tmp_path / "t.json"
    rc = cli.main(["tune", "--controller", family, *argv, "--json", str(js), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    assert seen["steps"] == steps
    assert seen.get("lr") == lr
    assert seen["train_dtype"] == dtype
    assert json.loads(js.read_text())["improvement_percent"] == 50.0
    assert SHORT_STEPS["lqg"] == 30 and SHORT_LR == {"lqg": 0.1}
    assert TRAIN_DTYPE == {"pi_lambda": "float32"}


def test_tune_model_alone_tunes_against_the_model(tmp_path, monkeypatch, capsys):
    """`tune --model M` tunes against M, as its help and a tune sweep say (it used to tune a
    1-zone model's design on the 4-zone printer: 'the plant takes 4'); `--plant printer`
    still picks the printer."""
    import numpy as np

    from jthermo import io, tune
    from jthermo.models import StateSpace

    m = io.save(StateSpace(np.eye(1) * 0.5, np.ones((1, 1)), np.ones((1, 1))), tmp_path / "m.jtm")
    seen = {}

    def fake(kind):
        def run(fam, *a, **kw):
            seen[kind] = kw.get("plant")
            return {"controller": fam, "start_cost": 2.0, "tuned_cost": 1.0,
                    "improvement_percent": 50.0, "scenarios": {}, "history": [2.0]}
        return run

    monkeypatch.setattr(tune, "tune_own_plant", fake("own"))
    monkeypatch.setattr(tune, "tune_report", fake("printer"))
    assert cli.main(["tune", "--controller", "pi", "--model", str(m), "--quiet"]) == 0
    assert isinstance(seen.pop("own"), StateSpace) and not seen
    assert cli.main(["tune", "--controller", "pi", "--model", str(m), "--plant", "printer",
                     "--quiet"]) == 0, capsys.readouterr().err
    assert seen == {"printer": "printer"}


def test_tune_reports_its_own_gain(tmp_path, monkeypatch, capsys):
    """An LQG whose tuning kept its start still beats the lambda PI (`improvement_percent`):
    the report and the summary line also say what the tuning itself gained (0 %) and that it
    kept its start."""
    import numpy as np

    from jthermo import io, tune
    from jthermo.models import StateSpace

    m = io.save(StateSpace(np.eye(1) * 0.5, np.ones((1, 1)), np.ones((1, 1))), tmp_path / "m.jtm")
    monkeypatch.setattr(tune, "tune_own_plant", lambda fam, *a, **kw: {
        "controller": fam, "start_cost": 2.0, "tuned_cost": 2.0, "lambda_pi_cost": 40.0,
        "improvement_percent": 95.0, "moved": False, "scenarios": {}, "history": [0.0]})
    js = tmp_path / "t.json"
    assert cli.main(["tune", "--controller", "lqg", "--model", str(m), "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert json.loads(js.read_text())["tuned_vs_start_percent"] == 0.0
    assert "tuned_vs_start_percent=0" in out and "kept its start" in out
