"""A sweep over record lengths and zone counts: the simulated record's keys as parameters."""

import pytest

from jthermo import sweep
from jthermo.errors import ConfigError
from jthermo.sweep.tasks import simulated_bed

CFG = """
[sweep]
name = "lengths"
kind = "arx"
method = "grid"
[data]
noise = 0.02
[fixed]
na = 2
nb = 2
nk = 2
[space]
samples = [400, 500]
zones = [1, 2]
"""


def test_record_keys_are_trial_parameters(tmp_path):
    cfg = sweep.parse_config(CFG)
    rep = sweep.run_sweep(cfg, tmp_path / "r.jsonl")
    assert (rep["n_run"], rep["n_failed"]) == (4, 0)
    rows = sweep.read_results(tmp_path / "r.jsonl")
    by = {(r["params"]["samples"], r["params"]["zones"]): r for r in rows}
    for (T, z), r in by.items():
        # the trial fitted its own record: one fit percentage per output of that record
        assert len(r["metrics"]["fit_percent"]) == z
        assert "samples" not in r["metrics"]["options"] and "zones" not in r["metrics"]["options"]
        assert r["worker"]["maps"] is None or r["worker"]["maps"] > 0
    # each record as the trial would have simulated it: different lengths, different scores
    assert by[(400, 1)]["metrics"]["mean_fit_percent"] != by[(500, 1)]["metrics"]["mean_fit_percent"]
    assert simulated_bed({"samples": 400, "zones": 2}).n_samples == 400


def test_record_keys_refused_with_a_data_file():
    text = CFG.replace("noise = 0.02", 'data = "est.csv"')
    with pytest.raises(ConfigError, match="data file"):
        sweep.parse_config(text)


def test_identify_duration_parameter():
    cfg = sweep.parse_config(CFG.replace('kind = "arx"', 'kind = "identify"')
                             .replace("noise = 0.02", "")
                             .replace("samples = [400, 500]", "duration = [300.0, 400.0]")
                             .replace("zones = [1, 2]", "family = [\"arx\"]"))
    assert {t["params"]["duration"] for t in sweep.trials(cfg)} == {300.0, 400.0}
