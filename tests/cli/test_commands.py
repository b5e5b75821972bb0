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
        (["--common-denominator"], "only for oe and bj, not arx"),
        (["--rest-level", "20,x"], "comma-separated numbers"),
        (["--rest-level", "20,21,22"], "2 numbers \\(one per output\\)"),
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
    assert not any(o["shifted"] for o in rep["level_offsets"] + rep2["level_offsets"])
    # a record at another level on output 2: the fit falls, and the note says why
    mat = np.loadtxt(val, delimiter=",", skiprows=1)
    mat[:, 4] += 30.0
    shifted = tmp_path / "shifted.csv"
    np.savetxt(shifted, mat, delimiter=",", header="t,u_1,u_2,y_1,y_2", comments="", fmt="%.10g")
    rc, _, err = _run(["validate", model, shifted, "--json", js2, "--quiet"], capsys)
    assert rc == 0, err
    rep3 = json.loads(js2.read_text())
    assert [o["shifted"] for o in rep3["level_offsets"]] == [False, True]
    assert rep3["level_offsets"][1]["mean_error"] == pytest.approx(30.0, rel=0.1)  # x0 takes a little
    assert "note: the record sits at another level" in err and "mean error 2 +2" in err and "error 1" not in err
    # a data file given as the model is a one-line error
    rc, _, err = _run(["validate", val, val], capsys)
    assert rc == 2 and "not a jthermo save file" in _one_line_error(err)


def test_fit_leaves_out_a_heater_never_switched_on(tmp_path, capsys):
    """A record that logs a heater held off: fit leaves it out with a note, validate picks the
    model's inputs from a record with it, and refuses one where it varies."""
    def with_idle(src, dst, idle=True):
        mat = np.loadtxt(src, delimiter=",", skiprows=1)
        mat = np.column_stack([mat[:, :3], np.zeros(len(mat)) if idle else mat[:, 1], mat[:, 3:]])
        np.savetxt(dst, mat, delimiter=",", header="t,u_1,u_2,u_3,y_1,y_2", comments="", fmt="%.10g")
        return dst

    est = with_idle(_arx_csv(tmp_path / "e.csv", seed=0), tmp_path / "est.csv")
    val = with_idle(_arx_csv(tmp_path / "v.csv", seed=1), tmp_path / "val.csv")
    js, model = tmp_path / "fit.json", tmp_path / "m.jtm"
    rc, _, err = _run(["fit", est, "--model", "arx", "--orders", "1,1,1", "--validation", val,
                       "--out", model, "--json", js, "--quiet"], capsys)
    assert rc == 0, err
    assert "warning: u_3 constant in the record: left out of the model" in err
    rep = json.loads(js.read_text())
    assert rep["inputs"] == ["1", "2"] and rep["dropped_inputs"] == ["3"] and rep["mean_fit_percent"] > 90
    assert io.load_model(model).n_inputs == 2
    rc, _, err = _run(["validate", model, val, "--json", js, "--quiet"], capsys)
    assert rc == 0, err
    np.testing.assert_allclose(json.loads(js.read_text())["fit_percent"], rep["fit_percent"], rtol=1e-10)
    busy = with_idle(_arx_csv(tmp_path / "b.csv", seed=2), tmp_path / "busy.csv", idle=False)
    rc, _, err = _run(["validate", model, busy], capsys)
    assert rc == 2 and "input `u_3` varies in this record, but the model has no such input" in _one_line_error(err)
    # one sensor only (--outputs): validate takes it from the full record
    rc, _, err = _run(["fit", est, "--model", "arx", "--orders", "1,1,1", "--outputs", "2",
                       "--out", model, "--json", js, "--quiet"], capsys)
    assert rc == 0, err
    rep = json.loads(js.read_text())
    assert rep["outputs"] == ["2"] and len(rep["fit_percent"]) == 1 and io.load_model(model).n_outputs == 1
    rc, _, err = _run(["validate", model, val, "--json", js, "--quiet"], capsys)
    assert rc == 0 and len(json.loads(js.read_text())["fit_percent"]) == 1, err
    rc, _, err = _run(["tune", "--controller", "pi", "--model", model], capsys)   # 2 heaters, 1 sensor
    assert rc == 2 and "one sensor per heater" in _one_line_error(err) and "--outputs" in err
    rc, _, err = _run(["fit", est, "--model", "arx", "--outputs", "9"], capsys)
    assert rc == 2 and "--outputs: no output `y_9`" in _one_line_error(err)
    # every input idle: refused as before
    mat = np.loadtxt(est, delimiter=",", skiprows=1)
    mat[:, 1:4] = 0.5
    still = tmp_path / "still.csv"
    np.savetxt(still, mat, delimiter=",", header="t,u_1,u_2,u_3,y_1,y_2", comments="", fmt="%.10g")
    rc, _, err = _run(["fit", still, "--model", "arx", "--orders", "1,1,1"], capsys)
    assert rc == 2 and "is constant" in _one_line_error(err)


def test_fit_common_denominator_and_rest_level(tmp_path, capsys):
    """`--common-denominator`: the saved OE model has one F per output, equal across inputs;
    `--rest-level`: its operating point is that level at zero input (88.5 °C is the data's
    steady state at u = 0)."""
    est = _arx_csv(tmp_path / "est.csv")
    js, model = tmp_path / "fit.json", tmp_path / "m.jtm"
    rc, _, err = _run(["fit", est, "--model", "oe", "--orders", "1,1,1", "--common-denominator",
                       "--rest-level", "88.5", "--out", model, "--json", js, "--quiet"], capsys)
    assert rc == 0, err
    assert json.loads(js.read_text())["mean_fit_percent"] > 80
    saved = io.load_model(model)
    f = np.asarray(saved.f)
    np.testing.assert_array_equal(f, np.broadcast_to(f[:, :1], f.shape))
    np.testing.assert_array_equal(np.asarray(saved.y0), [88.5, 88.5])
    np.testing.assert_array_equal(np.asarray(saved.u0), [0.0, 0.0])


def test_generate(tmp_path, capsys):
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


def test_generate_records_of_one_printer(tmp_path, capsys):
    """`--seed` draws another record of the same printer; `--printer-seed` another printer.

    Both records start at the printer's equilibrium at the mean input, so records of one
    printer start at the same temperatures (to the 0.05 °C noise), while another printer's
    zone-to-zone variation (±8 % loss and heater power) moves them by degrees."""
    from jthermo import data

    def first_sample(*opts):
        out = tmp_path / f"r{len(list(tmp_path.iterdir()))}.csv"
        rc, _, err = _run(["generate", "--zones", "3", "--duration", "30", "--out", out, "--quiet",
                           *opts], capsys)
        assert rc == 0, err
        return np.asarray(data.load(out).y)[0]

    a, b = first_sample("--seed", "1"), first_sample("--seed", "2")
    other = first_sample("--seed", "1", "--printer-seed", "1")
    assert np.max(np.abs(a - b)) < 0.5
    assert np.max(np.abs(a - other)) > 1.0
    js = tmp_path / "g.json"
    rc, _, err = _run(["generate", "--zones", "2", "--duration", "30", "--out", tmp_path / "p.csv",
                       "--printer-seed", "4", "--json", js, "--quiet"], capsys)
    assert rc == 0 and json.loads(js.read_text())["printer_seed"] == 4


def test_simulate_runs_the_printer_that_tune_and_generate_use(tmp_path, capsys):
    """`--seed` draws the scenarios only; the printer is `--printer-seed`'s (default 0, the
    printer `tune` tunes on and `generate` records): `--seed 5` used to simulate printer 5."""
    def run(*opts):
        js = tmp_path / f"s{len(list(tmp_path.iterdir()))}.json"
        rc, _, err = _run(["simulate", "--scenario", "tracking", "--controller", "pi_lambda",
                           "--zones", "2", "--rollouts", "2", "--duration", "120", "--json", js,
                           "--quiet", *opts], capsys)
        assert rc == 0, err
        rep = json.loads(js.read_text())
        return rep["printer_seed"], rep["cost"]

    default, same, other = run("--seed", "5"), run("--seed", "5", "--printer-seed", "0"), \
        run("--seed", "5", "--printer-seed", "5")
    assert default == same and default[0] == 0
    assert other[0] == 5 and other[1] != default[1]


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
    from jthermo.models import StateSpace

    m = io.save(StateSpace(np.eye(1) * 0.5, np.ones((1, 1)), np.ones((1, 1))), tmp_path / "m.jtm")
    rc, _, err = _run(["simulate", "--scenario", "tracking", "--controller-file", m], capsys)
    assert rc == 2 and "holds a model" in _one_line_error(err)
    # --printer-seed picks a virtual printer: with a fitted plant it is refused, not ignored
    for cmd in (["simulate", "--scenario", "tracking", "--controller", "pi_lambda"],
                ["tune", "--controller", "pi"]):
        rc, _, err = _run([*cmd, "--plant", m, "--printer-seed", "3"], capsys)
        assert rc == 2 and "--printer-seed is for the virtual printer" in _one_line_error(err)
        # so are --zones and --powder (a 1-zone model with --zones 3 ran silently on 1 zone)
        for opt, val in (("--zones", "3"), ("--powder", "PA11")):
            rc, _, err = _run([*cmd, "--plant", m, opt, val], capsys)
            assert rc == 2 and f"{opt} is for the virtual printer" in _one_line_error(err)


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


# ---------------------------------------------------------------- progress, report, demo pieces


def test_progress_quiet_and_callback_forms(monkeypatch):
    from jthermo import progress as pg

    monkeypatch.delenv("CI", raising=False)
    assert pg.enabled() is False              # pytest captures stderr: not a TTY
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    assert pg.enabled() is True and pg.enabled(quiet=True) is False
    monkeypatch.setenv("CI", "1")
    assert pg.enabled() is False
    monkeypatch.delenv("CI")
    pg.set_quiet(True)
    try:
        assert pg.enabled() is False
    finally:
        pg.set_quiet(False)
    assert list(pg.progress(3, "x", quiet=True)) == [0, 1, 2]
    with pg.Progress(10, "t", quiet=True) as bar:
        bar.update(2, cost=1.5)
        bar(5, 10, {"cost": 0.5})              # (i, total, info)
        assert bar.n == 5 and bar.info["cost"] == 0.5
        bar(6, 0.25)                           # tuning's (i, cost): iteration 6 done
        assert bar.n == 7 and bar.info["cost"] == 0.25
        bar("choosing orders")                 # identification's status strings
        assert bar.info["status"] == "choosing orders" and not bar.active


def test_report_markdown(tmp_path):
    from jthermo.report import Report, fmt, markdown_table

    assert fmt(None) == "—" and fmt(float("nan")) == "—" and fmt(1.23456) == "1.235" and fmt(True) == "yes"
    t = markdown_table([{"a": 1.0, "b": "x|y"}, {"a": None}], ["a", "b"])
    assert t.splitlines() == ["| a | b |", "| --- | --- |", "| 1 | x\\|y |", "| — | — |"]
    (tmp_path / "figs").mkdir()
    rep = Report("T").para("hello").figure(tmp_path / "figs" / "a.png", "cap").table([{"k": 2}])
    text = rep.write(tmp_path / "out" / "report.md").read_text()
    assert "# T" in text and "![cap](../figs/a.png)" in text and "| k |" in text


def test_demo_background_stage_result_and_error():
    """A stage run in a background thread hands its result, or its exception, to the stage that
    waits for it: the guard reports the failure with its one-line reason, as for any stage."""
    import threading

    from jthermo import demo
    from jthermo.errors import FitError

    started = threading.Event()

    def slow():
        started.wait(5.0)
        return threading.current_thread().name

    def failing():
        raise FitError("no start point converged")

    waiting_ok, waiting_bad = demo.in_background(slow), demo.in_background(failing)
    started.set()
    st = demo.StageRunner(2, quiet=True)
    assert st.run("ok", waiting_ok) == "demo-slow"
    assert st.run("bad", waiting_bad) is None
    assert [r["status"] for r in st.records] == ["ok", "failed"]
    assert st.records[1]["message"] == "no start point converged"


def test_demo_stage_guard_and_report(tmp_path):
    from jthermo import demo
    from jthermo.errors import FitError

    st = demo.StageRunner(3, quiet=True)

    def missing():
        import jthermo.not_written_yet  # noqa: F401

    def failing():
        raise FitError("no start point converged")

    assert st.run("a", lambda: 42) == 42
    st.run("b", missing)
    st.run("c", failing)
    assert [r["status"] for r in st.records] == ["ok", "missing", "failed"]
    assert "jthermo.not_written_yet" in st.records[1]["message"]
    S = {"name": "t", "quick": True, "seed": 0, "settings": {"zones": 4}, "seconds": 1.0,
         "stages": st.records,
         "identification": [{"model": "arx", "orders": {"na": 2}, "fit_percent": [90.0, 91.0],
                             "mean_fit_percent": 90.5, "converged": True, "seconds": 1.0},
                            {"model": "oe", "error": "diverged"}],
         "tuning": {"start_cost": 2.0, "tuned_cost": 1.0, "lambda_pi_cost": 2.0, "improvement_percent": 50.0,
                    "rollouts": 4, "steps": 10, "held_out_seeds": [10000],
                    "scenarios": {"tracking": {"mse_before": 1.0, "mse_after": 0.5}}},
         "diagnosis": {"verdict": "mismatch", "baseline": {"mean_fit_percent": 80.0},
                       "augmented": {"mechanisms": ["heater_lag"], "mean_fit_percent": 95.0},
                       "findings": [{"mechanism": "heater_lag", "confidence": 0.99, "zones": [1, 2],
                                     "parameters": {"time_constant_s": 24.0}, "summary": "lamps lag"}],
                       "concealed": {"mechanism": "heater_lag", "time_constant_s": 25.0}}}
    text = demo.write_demo_report(tmp_path, S, {}).read_text()
    assert "| arx |" in text and "diverged" in text and "heater_lag" in text
    assert "Stages that did not complete" in text and "no start point converged" in text


# ---------------------------------------------------------------- tune, simulate, diagnose wiring


def _pi_1zone():
    from jthermo.control.design import design
    from jthermo.models import StateSpace

    m = StateSpace(np.array([[0.98]]), np.array([[0.3]]), np.array([[1.0]]), ts=1.0, u0=[0.5], y0=[174.0])
    return design("pi_lambda", m)


def test_tune_saves_controller_and_simulate_runs_it(tmp_path, capsys, monkeypatch):
    from jthermo import tune

    ctrl = _pi_1zone()
    seen = {}

    def fake_tune_report(family, **kw):
        seen.update(kw, family=family)
        kw["progress"](0, 2.0)
        kw["progress"](1, 1.0)
        return {"controller": family, "start_cost": 2.0, "tuned_cost": 1.0, "lambda_pi_cost": 2.0,
                "improvement_percent": 50.0, "scenarios": {}, "history": [2.0, 1.0], "seconds": 0.1,
                "tuned": ctrl}

    monkeypatch.setattr(tune, "tune_report", fake_tune_report)
    out, js = tmp_path / "c.jtm", tmp_path / "t.json"
    rc, _, err = _run(["tune", "--controller", "pi", "--rollouts", "3", "--steps", "2",
                       "--seed", "4", "--zones", "2", "--powder", "PA11", "--out", out,
                       "--json", js, "--quiet"], capsys)
    assert rc == 0, err
    assert seen["rollouts"] == 3 and seen["steps"] == 2 and seen["seed"] == 4 and seen["plant"] == "printer"
    assert seen["family"] == "pi_lambda" and seen["zones"] == 2 and seen["powder"] == "PA11"
    rep = json.loads(js.read_text())
    assert rep["improvement_percent"] == 50.0 and "tuned" not in rep and rep["out"] == str(out)
    assert io.load_header(out)["kind"] == "controller"
    rc, _, err = _run(["tune", "--controller", "nope"], capsys)
    assert rc == 2 and "unknown family 'nope'" in _one_line_error(err)
    # the saved controller drives a one-zone printer
    js2 = tmp_path / "s.json"
    rc, _, err = _run(["simulate", "--scenario", "tracking", "--controller-file", out, "--zones", "1",
                       "--rollouts", "2", "--duration", "60", "--json", js2, "--quiet"], capsys)
    assert rc == 0, err
    rep = json.loads(js2.read_text())
    for key in ("scenario", "controller", "zones", "rollouts", "metrics", "seconds"):
        assert key in rep
    assert rep["zones"] == 1 and rep["rollouts"] == 2 and np.isfinite(rep["metrics"]["mse"])
    # a controller for 1 zone on a 2-zone printer is a one-line error
    rc, _, err = _run(["simulate", "--scenario", "tracking", "--controller-file", out, "--zones", "2",
                       "--duration", "60", "--json", tmp_path / "x.json"], capsys)
    assert rc == 2 and _one_line_error(err) and not (tmp_path / "x.json").exists()


def test_diagnose_wiring(tmp_path, capsys, monkeypatch):
    from jthermo import diagnose as diag

    est, val = _arx_csv(tmp_path / "est.csv"), _arx_csv(tmp_path / "val.csv", seed=1)

    def fake(e, v, *, seed, progress, actuator):
        assert e.n_outputs == 2 and seed == 7 and actuator == "any"
        return {"verdict": "no_significant_mismatch", "baseline": {"model": "greybox", "mean_fit_percent": 90.0,
                                                                   "fit_percent": [90.0, 90.0]},
                "findings": [], "augmented": None, "_arrays": np.zeros(3)}

    monkeypatch.setattr(diag, "diagnose", fake)
    js = tmp_path / "d.json"
    rc, out, err = _run(["diagnose", est, "--validation", val, "--json", js, "--seed", "7"], capsys)
    assert rc == 0, err
    rep = json.loads(js.read_text())
    assert rep["verdict"] == "no_significant_mismatch" and "_arrays" not in rep and rep["findings"] == []
    assert "verdict: no_significant_mismatch" in out and "--design-experiment" not in out
    # an uncertain finding is named so, with its rivals, and the separating experiment is offered
    tied = {"mechanism": "ambient_variation", "uncertain": True, "rivals": ["heat_accumulation"],
            "below_noise": False}
    small = {"mechanism": "radiative_loss", "uncertain": False, "rivals": [], "below_noise": True}
    monkeypatch.setattr(diag, "diagnose", lambda e, v, **kw: {"verdict": "mismatch", "findings": [tied, small]})
    rc, out, err = _run(["diagnose", est, "--validation", val], capsys)
    assert rc == 0, err
    assert ("findings: ambient_variation (uncertain, or heat_accumulation), radiative_loss (effect below the "
            "sensor noise)") in out
    assert "--design-experiment OUT.csv" in out
    rc, _, err = _run(["diagnose", est, "--json", js], capsys)
    assert rc == 2 and "--validation" in _one_line_error(err)


@pytest.mark.parametrize("zones", [1, 16])
def test_demo_zones_reach_every_printer_and_the_tuning(tmp_path, monkeypatch, capsys, zones):
    """`jthermo demo --zones N`: every stage's printer and the tuning get N zones (the stages
    are stopped at their first printer: the whole demo at 16 zones is measured by
    `python experiments/printer_scale.py --others demo`); the tie settled by an experiment is
    a one-zone case at any `--zones`, stopped before its printer."""
    import jthermo.diagnose.tie_demo
    import jthermo.printer
    import jthermo.tune
    from jthermo import demo
    from jthermo.errors import ConfigError

    seen = []

    def no_printer(n, *a, **k):
        seen.append(n)
        raise ConfigError("stopped here")

    def no_tuning(*a, zones=None, **k):
        seen.append(("tune", zones))
        raise ConfigError("stopped here")

    monkeypatch.setattr(jthermo.printer, "make_printer", no_printer)
    def no_tie(*a, **k):
        seen.append("tie")
        raise ConfigError("stopped here")

    monkeypatch.setattr(jthermo.tune, "tune_report", no_tuning)
    monkeypatch.setattr(jthermo.diagnose.tie_demo, "settle_tie", no_tie)
    rc, _, _ = _run(["demo", "--quick", "--zones", str(zones), "--runs-dir", str(tmp_path),
                     "--quiet", "--json", str(tmp_path / "r.json")], capsys)
    assert rc == 0
    assert ("tune", zones) in seen and "tie" in seen
    assert set(seen) - {("tune", zones), "tie"} == {zones}
    assert len(seen) >= 4               # experiment, diagnosis, design, tuning
    assert demo.demo_settings(False)["zones"] == 4 and demo.demo_settings(True, zones)["zones"] == zones
    with pytest.raises(ConfigError, match="positive integer"):
        demo.demo_settings(True, 0)
    rc, _, err = _run(["demo", "--zones", "0"], capsys)
    assert rc == 2 and "--zones" in err
