"""The `jthermo` command, in-process through `jthermo.cli.main(argv)`."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jthermo import cli, io

pytestmark = pytest.mark.filterwarnings("ignore")


def _arx_csv(path, T=400, seed=0, nw=0):
    """1st-order two-zone data (°C, u in [0, 1]) from a known diagonal ARX system."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([0.2, 0.8], size=(T // 10 + 1, 2)), 10, axis=0)[:T]
    y = np.zeros((T, 2))
    y[0] = 100.0
    for k in range(1, T):
        y[k] = 100.0 + 0.9 * (y[k - 1] - 100.0) + 2.0 * (u[k - 1] - 0.5) + 0.3 * (u[k - 1, ::-1] - 0.5)
    y = y + 0.01 * rng.standard_normal((T, 2))
    cols = ["t", "u_1", "u_2", "y_1", "y_2"]
    mat = np.column_stack([np.arange(T), u, y])
    np.savetxt(path, mat, delimiter=",", header=",".join(cols), comments="", fmt="%.10g")
    return path


def _run(argv, capsys):
    rc = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line_error(err):
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("jthermo: error:") and "Traceback" not in err
    return lines[0]


def test_help_and_version(capsys):
    rc, out, _ = _run(["--help"], capsys)
    assert rc == 0 and "fit" in out and "sweep" in out
    rc, out, _ = _run(["fit", "--help"], capsys)
    assert rc == 0 and "--orders" in out and "--validation" in out
    rc, out, _ = _run(["--version"], capsys)
    assert rc == 0 and out.startswith("jthermo ")
    rc, _, err = _run([], capsys)
    assert rc == 2


@pytest.mark.parametrize("argv, msg", [
    (["fit", "x.csv"], "required: --model"),
    (["fit", "x.csv", "--model", "nope"], "invalid choice: 'nope'"),
    (["nope"], "invalid choice"),
    (["simulate", "--scenario", "tracking", "--controller", "pi_lambda", "--zones", "0"], "must lie in 1..256"),
    (["simulate", "--scenario", "tracking", "--controller", "pi_lambda", "--duration", "inf"], "duration must lie in"),
    (["generate", "--zones", "2", "--duration", "10", "--out", "o.csv", "--seed", "-1"], "seed must lie in"),
    (["fit", "x.csv", "--model", "arx", "--bogus"], "unrecognized arguments: --bogus"),
])
def test_usage_errors_are_one_line(argv, msg, capsys):
    rc, _, err = _run(argv, capsys)
    assert rc == 2
    assert msg in _one_line_error(err)


def test_fit_option_errors_write_nothing(tmp_path, capsys):
    est = _arx_csv(tmp_path / "est.csv")
    js, out = tmp_path / "r.json", tmp_path / "m.jtm"
    cases = [
        (["--orders", "1,1"], "arx takes 3 orders"),
        (["--orders", "1,x,1"], "comma-separated integers"),
        (["--orders", "1,1,99"], "nk must lie in 0..64"),
        (["--validation", tmp_path / "missing.csv"], "validation data .*missing.csv: no such file"),
        (["--out", tmp_path], "is a directory"),
    ]
    for extra, msg in cases:
        rc, _, err = _run(["fit", est, "--model", "arx", "--json", js, "--out", out, *extra], capsys)
        assert rc == 2
        import re
        assert re.search(msg, _one_line_error(err)), err
        assert not js.exists() and not out.exists()
    rc, _, err = _run(["fit", est, "--model", "arx", "--json", js, "--out", js], capsys)
    assert rc == 2 and "same file" in _one_line_error(err)


def test_fit_validate_round_trip(tmp_path, capsys):
    pytest.importorskip("jthermo.identify.fit")
    est, val = _arx_csv(tmp_path / "est.csv", seed=0), _arx_csv(tmp_path / "val.csv", seed=1)
    js, model = tmp_path / "fit.json", tmp_path / "m.jtm"
    rc, out, err = _run(["fit", est, "--model", "arx", "--orders", "1,1,1", "--validation", val,
                         "--out", model, "--json", js, "--quiet"], capsys)
    assert rc == 0, err
    rep = json.loads(js.read_text())
    for key in ("model", "orders", "fit_percent", "mean_fit_percent", "seconds", "converged"):
        assert key in rep
    assert rep["model"] == "arx" and rep["orders"] == {"na": 1, "nb": 1, "nk": 1}
    assert len(rep["fit_percent"]) == 2 and rep["mean_fit_percent"] > 90 and rep["fit_on"] == "validation"
    header = io.load_header(model)
    assert header["family"] == "arx" and header["orders"] == {"na": 1, "nb": 1, "nk": 1}
    # validate the saved model: the same fit
    js2 = tmp_path / "val.json"
    rc, _, err = _run(["validate", model, val, "--json", js2, "--quiet"], capsys)
    assert rc == 0, err
    rep2 = json.loads(js2.read_text())
    np.testing.assert_allclose(rep2["fit_percent"], rep["fit_percent"], rtol=1e-10)
    assert rep2["model"] == "arx" and "whiteness_pass" in rep2["residual_tests"]
    # a data file given as the model is a one-line error
    rc, _, err = _run(["validate", val, val], capsys)
    assert rc == 2 and "not a jthermo save file" in _one_line_error(err)


def test_generate(tmp_path, capsys):
    pytest.importorskip("jthermo.printer")
    out, js = tmp_path / "d.csv", tmp_path / "g.json"
    rc, _, err = _run(["generate", "--experiment", "prbs", "--zones", "2", "--duration", "60",
                       "--out", out, "--json", js, "--seed", "3", "--quiet"], capsys)
    assert rc == 0, err
    from jthermo import data

    d = data.load(out)
    assert d.n_inputs >= 2 and d.n_outputs >= 2 and d.n_samples == 60
    rep = json.loads(js.read_text())
    assert rep["zones"] == 2 and rep["n_samples"] == 60
    rc, _, err = _run(["generate", "--zones", "2", "--duration", "60", "--out", tmp_path / "e.csv",
                       "--powder", "unobtainium"], capsys)
    assert rc == 2 and "unobtainium" in _one_line_error(err)
    assert not (tmp_path / "e.csv").exists()


def test_simulate_option_errors(tmp_path, capsys):
    rc, _, err = _run(["simulate", "--scenario", "tracking"], capsys)
    assert rc == 2 and "exactly one of --controller" in _one_line_error(err)
    bad = tmp_path / "c.jtm"
    bad.write_text("t,u_1\n")
    rc, _, err = _run(["simulate", "--scenario", "tracking", "--controller-file", bad,
                       "--json", tmp_path / "o.json"], capsys)
    assert rc == 2 and "not a jthermo save file" in _one_line_error(err)
    assert not (tmp_path / "o.json").exists()
    # a model file where a controller is expected
    from jthermo.models._base import StateSpace

    m = io.save(StateSpace(np.eye(1) * 0.5, np.ones((1, 1)), np.ones((1, 1))), tmp_path / "m.jtm")
    rc, _, err = _run(["simulate", "--scenario", "tracking", "--controller-file", m], capsys)
    assert rc == 2 and "holds a model" in _one_line_error(err)


def test_interrupt_and_internal_error(monkeypatch, tmp_path, capsys):
    def interrupted(args):
        raise KeyboardInterrupt

    def broken(args):
        raise TypeError("something\nunexpected")

    monkeypatch.setitem(cli.COMMANDS, "demo", interrupted)
    rc, _, err = _run(["demo"], capsys)
    assert rc == 130 and err.strip() == "jthermo: interrupted (saved files are intact)"
    monkeypatch.setitem(cli.COMMANDS, "demo", broken)
    rc, _, err = _run(["demo"], capsys)
    assert rc == 2 and _one_line_error(err) == "jthermo: error: internal error (TypeError): something unexpected"


def test_sweep_run_resume_summary(tmp_path, capsys):
    cfg = tmp_path / "s.toml"
    cfg.write_text('[sweep]\nname = "t"\nkind = "arx"\n[data]\nzones = 1\nsamples = 300\n'
                   '[space]\nna = [1, 2]\nnb = [1, 2]\nnk = [1]\n')
    res, js = tmp_path / "r.jsonl", tmp_path / "s.json"
    rc, _, err = _run(["sweep", cfg, "--results", res, "--json", js, "--quiet"], capsys)
    assert rc == 0, err
    rep = json.loads(js.read_text())
    assert (rep["n_total"], rep["n_run"], rep["n_skipped"], rep["n_failed"]) == (4, 4, 0, 0)
    rc, _, _ = _run(["sweep", cfg, "--results", res, "--json", js, "--quiet"], capsys)
    rep = json.loads(js.read_text())
    assert (rep["n_run"], rep["n_skipped"]) == (0, 4)
    rc, out, _ = _run(["sweep", cfg, "--results", res, "--summary", "--top", "2"], capsys)
    assert rc == 0 and out.startswith("best 2 of 4 trials by mean_fit_percent (max)")
    bad = tmp_path / "bad.toml"
    bad.write_text("[sweep\n")
    rc, _, err = _run(["sweep", bad], capsys)
    assert rc == 2 and "not valid TOML" in _one_line_error(err)


def test_console_script_help_is_quick():
    exe = Path(sys.executable).parent / "jthermo"
    if not exe.exists():
        pytest.skip("console script not installed")
    r = subprocess.run([str(exe), "fit", "--help"], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "CI": "1"})
    assert r.returncode == 0 and "--orders" in r.stdout
    r = subprocess.run([str(exe), "fit", "missing.csv", "--model", "arx"], capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 2 and r.stderr.strip() == "jthermo: error: estimation data missing.csv: no such file"
