"""Sweeps: configuration, trial generation, append-as-you-go results, resume, pool and Ray."""

import json
import multiprocessing

import pytest

import jthermo
from jthermo import sweep
from jthermo.errors import ConfigError
from jthermo.sweep import runner

CFG = """
[sweep]
name = "t"
kind = "arx"
method = "grid"
[data]
zones = 1
samples = 300
[space]
na = [1, 2]
nb = [1, 2]
nk = [1]
"""


def test_default_config_is_valid():
    cfg = sweep.default_config()
    assert cfg["kind"] == "arx" and sweep.count_trials(cfg) == len(sweep.trials(cfg)) == 18
    assert cfg["objective"] == "mean_fit_percent" and cfg["direction"] == "max"


def test_grid_and_random_trials():
    cfg = sweep.parse_config(CFG)
    tr = sweep.trials(cfg)
    assert [t["params"] for t in tr] == [{"na": 1, "nb": 1, "nk": 1}, {"na": 1, "nb": 2, "nk": 1},
                                         {"na": 2, "nb": 1, "nk": 1}, {"na": 2, "nb": 2, "nk": 1}]
    assert len({t["id"] for t in tr}) == 4
    assert sweep.trial_id({"b": 1, "a": 2}) == sweep.trial_id({"a": 2, "b": 1})
    rnd = sweep.parse_config(CFG.replace('method = "grid"', 'method = "random"\nsamples = 5\nseed = 3')
                             .replace("nb = [1, 2]", "nb = {low = 1, high = 4}\nrtol = {low = 0.001, high = 1.0, log = true}"))
    a, b = sweep.trials(rnd), sweep.trials(rnd)
    assert a == b and 1 <= len(a) <= 5
    for t in a:
        assert 1 <= t["params"]["nb"] <= 4 and isinstance(t["params"]["nb"], int)
        assert 0.001 <= t["params"]["rtol"] <= 1.0


@pytest.mark.parametrize("text, msg", [
    ("[space]\na=[1]", "missing \\[sweep\\] table"),
    ('[sweep]\nname="x"\nkind="nope"\n[space]\na=[1]', "kind must be one of"),
    ('[sweep]\nname="x"\nkind="arx"\nmethod="bayes"\n[space]\na=[1]', "method must be 'grid' or 'random'"),
    ('[sweep]\nname="x"\nkind="arx"\n', "missing or empty \\[space\\]"),
    ('[sweep]\nname="x"\nkind="arx"\n[space]\na=[]', "`a` is an empty list"),
    ('[sweep]\nname="x"\nkind="arx"\n[space]\na={low=1,high=2}', "ranges need method = 'random'"),
    ('[sweep]\nname="x"\nkind="arx"\nmethod="random"\n[space]\na={low=2,high=1}', "range needs numbers low <= high"),
    ('[sweep]\nname="x"\nkind="arx"\nmethod="random"\n[space]\na={low=0,high=1,log=true}', "log range needs low > 0"),
    ('[sweep]\nname="x"\nkind="arx"\n[space]\na=3', "must be a list of values or a range table"),
    ('[sweep]\nname="x"\nkind="arx"\ncolour="red"\n[space]\na=[1]', "unknown key `colour`"),
    ('[sweep]\nname="x"\nkind="arx"\n[space]\na=[1]\n[other]\nb=1', "unknown table \\[other\\]"),
    ('[sweep]\nname="a/b"\nkind="arx"\n[space]\na=[1]', "needs a plain `name`"),
    ("[sweep", "not valid TOML"),
])
def test_config_errors(text, msg):
    with pytest.raises(ConfigError, match=msg):
        sweep.parse_config(text)


def test_load_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="no such file"):
        sweep.load_config(tmp_path / "none.toml")
    (tmp_path / "b.toml").write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="not a text TOML file"):
        sweep.load_config(tmp_path / "b.toml")


def test_run_resume_and_torn_line(tmp_path):
    cfg = sweep.parse_config(CFG)
    res = tmp_path / "r.jsonl"
    calls = []
    rep = sweep.run_sweep(cfg, res, progress=lambda i, n, info: calls.append((i, n)))
    assert (rep["n_total"], rep["n_run"], rep["n_failed"]) == (4, 4, 0)
    assert calls == [(1, 4), (2, 4), (3, 4), (4, 4)]
    rows = sweep.read_results(res)
    assert len(rows) == 4 and all(r["status"] == "ok" for r in rows)
    assert rep["best"][0]["score"] == max(r["metrics"]["mean_fit_percent"] for r in rows)
    # a kill in the middle of a write: drop the last record and leave half a line behind
    lines = res.read_text().splitlines(keepends=True)
    res.write_text("".join(lines[:2]) + lines[2][: len(lines[2]) // 2])
    assert len(sweep.read_results(res)) == 2
    rep = sweep.run_sweep(cfg, res)
    assert (rep["n_skipped"], rep["n_run"]) == (2, 2)
    rows = sweep.read_results(res)
    assert sorted(r["id"] for r in rows) == sorted(t["id"] for t in sweep.trials(cfg))
    assert all(json.loads(line) for line in res.read_text().splitlines())


def test_failed_trial_recorded(tmp_path):
    cfg = sweep.parse_config(CFG.replace("nb = [1, 2]", "nb = [-1, 1]"))
    rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl")
    assert rep["n_failed"] == 2
    bad = [r for r in sweep.read_results(tmp_path / "r.jsonl") if r["status"] == "error"]
    assert bad and "order nb must be an integer >= 0" in bad[0]["error"]
    assert len(sweep.best_trials(sweep.read_results(tmp_path / "r.jsonl"), cfg)) == 2


def test_summary_format():
    cfg = sweep.parse_config(CFG)
    salt = sweep.trial_salt()
    rows = [{"id": "a", "params": {"na": 1}, "status": "ok", "metrics": {"mean_fit_percent": 50.0}},
            {"id": "b", "params": {"na": 2}, "status": "ok", "metrics": {"mean_fit_percent": 70.0}},
            {"id": "c", "params": {"na": 3}, "status": "error", "error": "x"}]
    rows = [{**r, "salt": salt} for r in rows]
    best = sweep.best_trials(rows, cfg, top=5)
    assert [b["id"] for b in best] == ["b", "a"]
    text = sweep.format_summary(best, cfg, total=3)
    assert text.splitlines()[0] == "best 2 of 3 trials by mean_fit_percent (max):"
    assert "[b]" in text.splitlines()[1]


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")
def test_process_pool_matches_in_process(tmp_path):
    cfg = sweep.parse_config(CFG)
    sweep.run_sweep(cfg, tmp_path / "a.jsonl")
    rep = sweep.run_sweep(cfg, tmp_path / "b.jsonl", workers=2)
    assert rep["n_run"] == 4
    a = {r["id"]: r["metrics"] for r in sweep.read_results(tmp_path / "a.jsonl")}
    b = {r["id"]: r["metrics"] for r in sweep.read_results(tmp_path / "b.jsonl")}
    assert a == b


@pytest.mark.filterwarnings("ignore")
def test_ray_local(tmp_path):
    ray = pytest.importorskip("ray")
    try:
        ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False)
    except Exception as exc:  # noqa: BLE001
        pytest.skip(f"ray cannot start here: {exc}")
    try:
        cfg = sweep.parse_config(CFG)
        rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl", ray_address="local")
        assert (rep["n_run"], rep["n_failed"]) == (4, 0)
        local = sweep.run_sweep(cfg, tmp_path / "l.jsonl")
        a = {r["id"]: r["metrics"] for r in sweep.read_results(tmp_path / "r.jsonl")}
        b = {r["id"]: r["metrics"] for r in sweep.read_results(tmp_path / "l.jsonl")}
        assert a == b and local["n_run"] == 4
    finally:
        ray.shutdown()


@pytest.mark.filterwarnings("ignore")
def test_ray_bad_address(tmp_path):
    pytest.importorskip("ray")
    cfg = sweep.parse_config(CFG)
    with pytest.raises(ConfigError, match="--ray 127.0.0.1:1: cannot connect"):
        sweep.run_sweep(cfg, tmp_path / "r.jsonl", ray_address="127.0.0.1:1")


def test_identify_kind_on_a_data_file(tmp_path):
    import numpy as np

    rng = np.random.default_rng(0)
    T = 300
    u = np.repeat(rng.choice([0.2, 0.8], size=T // 10), 10)
    y = np.zeros(T)
    for k in range(1, T):
        y[k] = 0.9 * y[k - 1] + 2.0 * u[k - 1]
    y += 20 + 0.01 * rng.standard_normal(T)
    np.savetxt(tmp_path / "d.csv", np.column_stack([np.arange(T), u, y]), delimiter=",",
               header="t,u_1,y_1", comments="")
    cfg = sweep.parse_config(f'[sweep]\nname="i"\nkind="identify"\n[data]\ndata="{tmp_path / "d.csv"}"\n'
                             '[fixed]\nfamily="arx"\n[space]\nna=[1]\nnb=[1]\nnk=[1]\n')
    rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl")
    assert rep["n_run"] == 1 and rep["n_failed"] == 0, sweep.read_results(tmp_path / "r.jsonl")
    assert rep["best"][0]["score"] > 95
    cfg = sweep.parse_config(f'[sweep]\nname="i"\nkind="identify"\n[data]\ndata="{tmp_path / "d.csv"}"\n'
                             '[fixed]\nfamily="arx"\n[space]\nna=[1]\nnb=[1]\n')
    rep = sweep.run_sweep(cfg, tmp_path / "r2.jsonl")
    assert rep["n_failed"] == 1
    assert "needs all of the orders" in sweep.read_results(tmp_path / "r2.jsonl")[0]["error"]


# ---------------------------------------------------------------- the API as scripts use it

@pytest.mark.parametrize("text, msg", [
    ('[sweep]\nname="x"\nkind="arx"\n[data]\nsample=300\n[space]\nna=[1]',
     "unknown key `sample` in \\[data\\] for kind arx"),
    ('[sweep]\nname="x"\nkind="identify"\n[data]\nvalidaton="v.csv"\n[space]\nna=[1]',
     "unknown key `validaton` in \\[data\\] for kind identify"),
    ('[sweep]\nname="x"\nkind="arx"\n[space]\nna=[1]\nfocus=["simulation"]',
     "unknown parameter `focus` in \\[space\\] for kind arx"),
    ('[sweep]\nname="x"\nkind="tune"\n[fixed]\nw_track=1.0\n[space]\nsteps=[1]',
     "unknown parameter `w_track` in \\[fixed\\] for kind tune"),
    ('[sweep]\nname="x"\nkind="tune"\n[data]\nmodle="m.jtm"\n[space]\nsteps=[1]',
     "unknown key `modle` in \\[data\\]"),
])
def test_typos_in_names_are_errors(text, msg):
    with pytest.raises(ConfigError, match=msg):
        sweep.parse_config(text)


def test_known_names_pass():
    cfg = sweep.parse_config('[sweep]\nname="x"\nkind="identify"\n[data]\nfamily="ss"\n'
                             'n_starts=2\n[fixed]\nfocus="simulation"\n[space]\nn=[1,2]')
    assert cfg["data"] == {"family": "ss", "n_starts": 2}
    cfg = sweep.parse_config('[sweep]\nname="x"\nkind="tune"\n[data]\nmodel="m.jtm"\n'
                             'setpoint=[60.0]\n[space]\nw_effort=[0.1, 1.0]\ncontroller=["pi"]')
    assert sweep.count_trials(cfg) == 2


def test_arx_kind_is_fit_and_compare(tmp_path):
    """The `arx` score is exactly `compare(fit(est, "arx", orders).model, val)` on the halves."""
    from jthermo.data import split
    from jthermo.identify import fit
    from jthermo.sweep.tasks import simulated_bed
    from jthermo.validate import compare

    cfg = sweep.parse_config(CFG)
    rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl")
    assert rep["n_failed"] == 0
    rows = {tuple(r["params"][n] for n in ("na", "nb", "nk")): r["metrics"]
            for r in sweep.read_results(tmp_path / "r.jsonl")}
    est, val = split(simulated_bed(cfg["data"]), 0.5)
    for orders in [(1, 1, 1), (2, 2, 1)]:
        direct = compare(fit(est, "arx", orders).model, val)["mean_fit_percent"]
        assert rows[orders]["mean_fit_percent"] == pytest.approx(direct, abs=1e-9)
    assert rows[(2, 2, 1)]["mean_fit_percent"] > max(80.0, rows[(1, 1, 1)]["mean_fit_percent"])


def test_fit_options_pass_through(tmp_path):
    base = '[sweep]\nname="o"\nkind="identify"\n[data]\nzones=1\nduration=300\n'
    cfg = sweep.parse_config(base + '[fixed]\nfamily="arx"\noffset="mean"\n[space]\nna=[1]\nnb=[1]\nnk=[1]')
    sweep.run_sweep(cfg, tmp_path / "a.jsonl")
    (rec,) = sweep.read_results(tmp_path / "a.jsonl")
    assert rec["status"] == "ok" and rec["metrics"]["options"] == {"offset": "mean"}
    # an option of another family reaches `fit`, which refuses it for this one
    cfg = sweep.parse_config(base + '[fixed]\nfamily="arx"\nfocus="simulation"\n[space]\nna=[1]\nnb=[1]\nnk=[1]')
    sweep.run_sweep(cfg, tmp_path / "b.jsonl")
    (rec,) = sweep.read_results(tmp_path / "b.jsonl")
    assert rec["status"] == "error" and "unknown option `focus` for family arx" in rec["error"]


def test_in_process_sweep_leaves_jax_config_alone(tmp_path):
    """Trials run in float64 in a scoped context: same scores whatever the caller's setting,
    and the caller's setting is unchanged afterwards."""
    import jax

    before = jax.config.jax_enable_x64
    cfg = sweep.parse_config(CFG)
    try:
        for flag in (False, True):
            jax.config.update("jax_enable_x64", flag)
            sweep.run_sweep(cfg, tmp_path / f"{flag}.jsonl")
            assert jax.config.jax_enable_x64 is flag
    finally:
        jax.config.update("jax_enable_x64", before)
    a, b = ({r["id"]: r["metrics"] for r in sweep.read_results(tmp_path / f"{f}.jsonl")}
            for f in (False, True))
    assert a == b and len(a) == 4


def test_results_as_dataframe(tmp_path):
    cfg = sweep.parse_config(CFG.replace("nb = [1, 2]", "nb = [-1, 1, 2]"))
    rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl")
    df = rep.to_dataframe()
    assert len(df) == 6 and {"id", "status", "na", "nb", "nk", "mean_fit_percent",
                             "fit_percent_1", "seconds", "error"} <= set(df.columns)
    ok = df[df.status == "ok"]
    assert list(ok.mean_fit_percent) == sorted(ok.mean_fit_percent, reverse=True)
    assert list(df.status[-2:]) == ["error", "error"]         # failures last
    assert df.iloc[0]["id"] == rep["best"][0]["id"]
    assert len(sweep.results_frame(sweep.read_results(tmp_path / "r.jsonl"))) == 6
    assert json.loads(json.dumps(rep))["n_total"] == 6         # still a plain JSON report


def test_history_frame():
    import numpy as np

    from jthermo.tune import TuneResult

    res = TuneResult(controller=None, history=np.array([3.0, 2.0, 1.5]), start_cost=3.0,
                     tuned_cost=1.5)
    df = sweep.history_frame(res)
    assert list(df.columns) == ["iteration", "cost"] and list(df.cost) == [3.0, 2.0, 1.5]
    assert repr(res).splitlines()[0] == ("TuneResult: training cost 3 -> 1.5 over 3 iterations, "
                                         "guard not run, 0 s")
    assert list(sweep.history_frame({"history": [2.0, None]}).iteration) == [0, 1]
    with pytest.raises(ConfigError, match="carries no tuning history"):
        sweep.history_frame({"tuned_cost": 1.0})


def _fitted_model_file(tmp_path):
    """A one-heater record at Ts = 0.5 s (25 °C at rest, gain 80 °C, 3-sample delay) fitted
    by `jthermo fit --out`, which stores the recording's envelope with the model."""
    import numpy as np

    from jthermo import cli

    rng = np.random.default_rng(0)
    T, ts = 800, 0.5
    u = np.repeat(rng.uniform(0, 1, T // 80), 80)
    y = np.full(T, 25.0)
    for k in range(3, T):
        y[k] = 25.0 + 0.975 * (y[k - 1] - 25.0) + 0.025 * 80.0 * u[k - 3]
    y += 0.05 * rng.standard_normal(T)
    np.savetxt(tmp_path / "rec.csv", np.column_stack([ts * np.arange(T), u, y]), delimiter=",",
               header="t,u_h,y_T", comments="")
    model = tmp_path / "m.jtm"
    assert cli.main(["fit", str(tmp_path / "rec.csv"), "--model", "arx", "--orders", "1,1,3",
                     "--out", str(model), "--quiet"]) == 0
    return model


@pytest.mark.filterwarnings("ignore")
def test_tune_kind_routes_a_fitted_model(tmp_path, monkeypatch):
    """Which tuning a tune trial runs, with what: the user's model (design model, plant and
    its envelope) goes to `tune_own_plant`, the printer to `tune_report`."""
    from jthermo import io, tune

    model = _fitted_model_file(tmp_path)
    calls = []
    monkeypatch.setattr(tune, "tune_own_plant", lambda family, m, **kw: calls.append(
        ("own", family, m, kw)) or {"tuned_cost": 1.0, "history": [2.0, 1.0]})
    monkeypatch.setattr(tune, "tune_report", lambda family, **kw: calls.append(
        ("printer", family, None, kw)) or {"tuned_cost": 2.0})
    cfg = sweep.parse_config(f'[sweep]\nname="t"\nkind="tune"\n[data]\nmodel="{model}"\n'
                             'setpoint=[60.0]\nrollouts=1\n[space]\nsteps=[2]\nw_effort=[0.5]')
    assert sweep.run_sweep(cfg, tmp_path / "a.jsonl")["n_failed"] == 0
    kind, family, m, kw = calls[-1]
    assert (kind, family, kw["setpoint"], kw["steps"], kw["rollouts"]) == ("own", "pi_lambda", [60.0], 2, 1)
    assert kw["weights"] == {"effort": 0.5} and kw["plant"] is m and kw["envelope"].ts == 0.5
    assert type(m) is type(io.load_model(model))
    cfg = sweep.parse_config('[sweep]\nname="p"\nkind="tune"\n[space]\ncontroller=["lqg"]')
    assert sweep.run_sweep(cfg, tmp_path / "b.jsonl")["n_failed"] == 0
    assert calls[-1][:2] == ("printer", "lqg") and calls[-1][3]["model"] is None
    cfg = sweep.parse_config('[sweep]\nname="q"\nkind="tune"\n[data]\nsetpoint=60.0\n'
                             '[space]\ncontroller=["pi"]')
    sweep.run_sweep(cfg, tmp_path / "c.jsonl")
    assert "`setpoint` is for a fitted plant" in sweep.read_results(tmp_path / "c.jsonl")[0]["error"]


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore")
def test_tune_kind_on_a_fitted_model(tmp_path):
    """`model = "fit.jtm"`: the trial tunes the user's model at its own sample time and set
    point (not the printer's 1 s and window). Slow: it compiles the whole own-plant tuning."""
    model = _fitted_model_file(tmp_path)
    ts = 0.5
    cfg = sweep.parse_config(f'[sweep]\nname="t"\nkind="tune"\n[data]\nmodel="{model}"\n'
                             'setpoint=[60.0]\nrollouts=1\nduration=150.0\nclassical=["pi_lambda"]\n'
                             '[space]\nsteps=[2]\ncontroller=["pi"]')
    rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl")
    (rec,) = sweep.read_results(tmp_path / "r.jsonl")
    assert rep["n_failed"] == 0, rec.get("error")
    assert rec["metrics"]["setpoints"] == [60.0] and rec["metrics"]["ts"] == ts
    assert rec["metrics"]["best_classical"] == "pi_lambda"
    assert len(sweep.history_frame(rec["metrics"])) == len(rec["metrics"]["history"]) >= 2
    assert rep.to_dataframe().loc[0, "tuned_cost"] == rec["metrics"]["tuned_cost"]


def test_cli_sweep_with_a_typo_exits_2(tmp_path, capsys):
    from jthermo import cli

    (tmp_path / "s.toml").write_text('[sweep]\nname="x"\nkind="arx"\n[data]\nzone=2\n[space]\nna=[1]\n')
    assert cli.main(["sweep", str(tmp_path / "s.toml"), "--results", str(tmp_path / "r.jsonl")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "unknown key `zone` in [data] for kind arx" in err
    assert not (tmp_path / "r.jsonl").exists()


def test_cli_sweep_writes_a_csv_table(tmp_path):
    import pandas as pd

    from jthermo import cli

    (tmp_path / "s.toml").write_text(CFG)
    res, table = tmp_path / "r.jsonl", tmp_path / "t.csv"
    assert cli.main(["sweep", str(tmp_path / "s.toml"), "--results", str(res), "--csv", str(table),
                     "--quiet"]) == 0
    df = pd.read_csv(table)
    assert len(df) == 4 and list(df.columns[:5]) == ["id", "status", "na", "nb", "nk"]
    assert df.mean_fit_percent.is_monotonic_decreasing
    table.unlink()
    assert cli.main(["sweep", str(tmp_path / "s.toml"), "--results", str(res), "--summary",
                     "--csv", str(table), "--quiet"]) == 0
    assert pd.read_csv(table).id.tolist() == df.id.tolist()


# ---------------------------------------------------------------- version salt


def test_trial_ids_depend_on_the_salt_and_the_parameters(monkeypatch):
    p = {"na": 1, "nb": 2}
    assert sweep.trial_id(p) == sweep.trial_id({"nb": 2, "na": 1}) == sweep.trial_id(p, sweep.trial_salt())
    assert sweep.trial_id(p, "jthermo 0.1.0 trial 1") != sweep.trial_id(p, "jthermo 0.2.0 trial 1")
    assert sweep.trial_id(p) != sweep.trial_id({"na": 1, "nb": 3})
    assert jthermo.__version__ in sweep.trial_salt() and str(sweep.TRIAL_FORMAT) in sweep.trial_salt()
    old = sweep.trial_id(p)
    monkeypatch.setattr(sweep.config, "TRIAL_FORMAT", sweep.TRIAL_FORMAT + 1)
    assert sweep.trial_id(p) != old


def test_resume_after_an_upgrade_reruns_and_ignores_stale_rows(tmp_path, monkeypatch):
    cfg = sweep.parse_config(CFG)
    res = tmp_path / "r.jsonl"
    first = sweep.run_sweep(cfg, res)
    assert (first["n_run"], first["n_skipped"]) == (4, 0)
    rows = sweep.read_results(res)
    assert all(r["salt"] == sweep.trial_salt() for r in rows)
    again = sweep.run_sweep(cfg, res)
    assert (again["n_run"], again["n_skipped"]) == (0, 4)          # same version: resumed
    monkeypatch.setattr(jthermo, "__version__", jthermo.__version__ + ".post1")   # upgraded
    ids_after = {t["id"] for t in sweep.trials(cfg)}
    assert ids_after.isdisjoint(r["id"] for r in rows)
    with res.open("a") as f:           # an old row that would otherwise win
        f.write(json.dumps({**rows[0], "metrics": {"mean_fit_percent": 1e9}}) + "\n")
    upgraded = sweep.run_sweep(cfg, res)
    assert (upgraded["n_run"], upgraded["n_skipped"]) == (4, 0)    # nothing stale reused
    assert {b["id"] for b in upgraded["best"]} == ids_after
    assert all(b["score"] < 1e9 for b in upgraded["best"])
    df = upgraded.to_dataframe()
    assert set(df["id"]) == ids_after
    assert len(sweep.results_frame(sweep.read_results(res), cfg, stale=True)) == 8


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")
def test_sweep_pool_recycles_workers(tmp_path, monkeypatch):
    """A fresh pool every `workers * TRIALS_PER_WORKER` trials: every trial completes (a pool
    whose workers all reached `max_tasks_per_child` together hung on Python 3.11), each pool
    on fresh processes."""
    monkeypatch.setattr(runner, "TRIALS_PER_WORKER", 1)
    cfg = sweep.parse_config(CFG)
    rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl", workers=2)
    assert rep["n_run"] == 4
    pids = [r["worker"]["pid"] for r in sweep.read_results(tmp_path / "r.jsonl")]
    assert len(set(pids)) == 4
    assert "max_tasks_per_child" not in runner.pool_options(multiprocessing.get_context("spawn"))
