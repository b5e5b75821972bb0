"""Sweeps: configuration, trial generation, append-as-you-go results, resume, pool and Ray."""

import json

import pytest

from jthermo import sweep
from jthermo.errors import ConfigError

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
    assert cfg["kind"] == "arx" and sweep.count_trials(cfg) == len(sweep.trials(cfg)) == 48
    assert cfg["objective"] == "mean_fit_percent" and cfg["direction"] == "max"


def test_grid_and_random_trials():
    cfg = sweep.parse_config(CFG)
    tr = sweep.trials(cfg)
    assert [t["params"] for t in tr] == [{"na": 1, "nb": 1, "nk": 1}, {"na": 1, "nb": 2, "nk": 1},
                                         {"na": 2, "nb": 1, "nk": 1}, {"na": 2, "nb": 2, "nk": 1}]
    assert len({t["id"] for t in tr}) == 4
    assert sweep.trial_id({"b": 1, "a": 2}) == sweep.trial_id({"a": 2, "b": 1})
    rnd = sweep.parse_config(CFG.replace('method = "grid"', 'method = "random"\nsamples = 5\nseed = 3')
                             .replace("nb = [1, 2]", "nb = {low = 1, high = 4}\nw = {low = 0.001, high = 1.0, log = true}"))
    a, b = sweep.trials(rnd), sweep.trials(rnd)
    assert a == b and 1 <= len(a) <= 5
    for t in a:
        assert 1 <= t["params"]["nb"] <= 4 and isinstance(t["params"]["nb"], int)
        assert 0.001 <= t["params"]["w"] <= 1.0


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
    cfg = sweep.parse_config(CFG.replace("nb = [1, 2]", "nb = [0, 1]"))
    rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl")
    assert rep["n_failed"] == 2
    bad = [r for r in sweep.read_results(tmp_path / "r.jsonl") if r["status"] == "error"]
    assert bad and "invalid orders" in bad[0]["error"]
    assert len(sweep.best_trials(sweep.read_results(tmp_path / "r.jsonl"), cfg)) == 2


def test_summary_format():
    cfg = sweep.parse_config(CFG)
    rows = [{"id": "a", "params": {"na": 1}, "status": "ok", "metrics": {"mean_fit_percent": 50.0}},
            {"id": "b", "params": {"na": 2}, "status": "ok", "metrics": {"mean_fit_percent": 70.0}},
            {"id": "c", "params": {"na": 3}, "status": "error", "error": "x"}]
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
