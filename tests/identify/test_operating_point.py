"""One operating point per fitted plant (`models.operating`): `tune` and `simulate` (a family
name, `--model`, `--controller-file`) report the same set point and signal levels for the same
plant, and store it with the controller."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

from jthermo import cli, io  # noqa: E402
from jthermo.data import save_csv  # noqa: E402
from jthermo.models.envelope import Envelope  # noqa: E402
from jthermo.models.operating import operating_point  # noqa: E402

from .test_heat import _clean  # noqa: E402
from jthermo.data import from_arrays  # noqa: E402


def _fit_plant(tmp_path, n=1):
    """A fitted plant of `n` heaters and sensors (n = 2: TCLab-like) from a record that also
    logs a fan and a set point per sensor (left out of the plant)."""
    u, y = _clean(n, T=300)
    fan = np.where(np.arange(300) > 200, 1.0, 0.0)      # a fan, off mostly
    target = np.repeat(np.where(np.arange(300) < 150, 30.0, 35.0)[:, None], n, axis=1)
    w = np.column_stack([fan, target])
    names = ["fan_cmd"] + [f"T{i + 1}_setpoint" for i in range(n)]
    data = from_arrays(u, y, ts=1.0, w=w, signal_names=names)
    rec, model = tmp_path / "rec.csv", tmp_path / "p.jtm"
    save_csv(data, rec)
    assert cli.main(["fit", str(rec), "--model", "ss", "--out", str(model), "--quiet"]) == 0
    return data, model


@pytest.mark.parametrize("n", [1, 2])
def test_operating_point_is_the_plants_everywhere(tmp_path, capsys, monkeypatch, n):
    from jthermo import tune
    from jthermo.control.design import design

    data, pfile = _fit_plant(tmp_path, n)
    plant = io.load_model(pfile)
    assert plant.n_inputs == n and plant.n_signals == 1     # the fan; no set point
    env = io.load_envelope(pfile)
    op = operating_point(plant, env)
    # the default: the middle of the recorded range (reachable here), the fan at its median (0)
    assert np.allclose(op.setpoint, 0.5 * (data.y.min(0) + data.y.max(0)))
    assert op.signals == (0.0,) and not op.given
    seen = {}

    def fake(family, model, **kw):
        seen.update(kw)
        return {"controller": family, "setpoints": list(kw["setpoint"]),
                "tuned": design("pi_lambda", model, setpoint=kw["setpoint"])}

    monkeypatch.setattr(tune, "tune_own_plant", fake)
    ctrl, reports = tmp_path / "c.jtm", []
    argv = ["tune", "--controller", "pi", "--model", str(pfile), "--plant", str(pfile),
            "--steps", "1", "--out", str(ctrl)]
    runs = [argv, ["simulate", "--scenario", "tracking", "--controller", "pi_untuned", "--model", str(pfile), "--plant",
                   str(pfile), "--duration", "60", "--rollouts", "1"],
            ["simulate", "--scenario", "tracking", "--controller-file", str(ctrl), "--plant", str(pfile), "--duration",
             "60", "--rollouts", "1"]]
    for k, a in enumerate(runs):
        js = tmp_path / f"r{k}.json"
        rc = cli.main(a + ["--json", str(js)])
        out, err = capsys.readouterr()
        assert rc == 0, err
        assert "operating point: set point" in out + err
        reports.append(json.loads(js.read_text())["operating_point"])
    assert len(reports) == 3 and all(r == op.to_dict() for r in reports), reports
    assert len(op.setpoint) == n and op.signals == (0.0,)
    assert np.allclose(seen["setpoint"], op.setpoint)
    assert io.load_header(ctrl)["meta"]["operating_point"] == op.to_dict()
    # a given set point is the caller's
    js = tmp_path / "given.json"
    assert cli.main(runs[1] + ["--setpoint", "30", "--json", str(js)]) == 0
    assert json.loads(js.read_text())["operating_point"]["source"] == "given"


def test_signals_held_at_recorded_median():
    u, y = _clean(1)
    w = np.column_stack([np.r_[np.zeros(200), np.ones(100)]])
    env = Envelope.from_data(from_arrays(u, y, ts=1.0, w=w))
    assert env.w_median == (0.0,) and abs(env.w_mean[0] - 1 / 3) < 1e-12
    assert Envelope.from_dict(env.to_dict()) == env
