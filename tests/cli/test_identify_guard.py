"""`jthermo fit`: the checks of a fitted model reach the JSON report, and a model that fails
them is never written (one-line error, exit 2)."""

import json

import numpy as np
import pytest

from jthermo import cli

pytestmark = pytest.mark.filterwarnings("ignore")


def _csv(path, pole, T=300, seed=0):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([0.2, 0.8], size=(T // 10 + 1, 1)), 10, axis=0)[:T]
    y = np.zeros(T)
    for k in range(1, T):
        y[k] = pole * y[k - 1] + 0.5 * u[k - 1, 0]
    y = 20.0 + y + 0.01 * rng.standard_normal(T)
    np.savetxt(path, np.column_stack([np.arange(T), u[:, 0], y]), delimiter=",",
               header="t,u_1,y_1", comments="", fmt="%.10g")
    return path


def test_fit_json_carries_the_checks(tmp_path, capsys):
    est = _csv(tmp_path / "est.csv", 0.9)
    js = tmp_path / "fit.json"
    rc = cli.main(["fit", str(est), "--model", "arx", "--json", str(js), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    rep = json.loads(js.read_text())
    assert rep["checks"]["passed"] and rep["checks"]["stable"] and rep["converged"]
    assert rep["repaired"] is None
    assert any(r["chosen"] for r in rep["criterion_table"])


def test_unstable_fit_is_a_one_line_error_and_nothing_is_written(tmp_path, capsys):
    est = _csv(tmp_path / "est.csv", 1.01)          # a growing record: the ARX model is unstable
    js, out = tmp_path / "fit.json", tmp_path / "m.jtm"
    rc = cli.main(["fit", str(est), "--model", "arx", "--orders", "1,1,1", "--json", str(js),
                   "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "unstable" in err[0] and "Traceback" not in err[0]
    assert not js.exists() and not out.exists()
