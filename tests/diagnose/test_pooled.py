"""Pooled estimation records (`jthermo.diagnose.pool`): one plant's records fitted jointly.

The pooled simulations and baseline are checked against a first-order recurrence written out
here; the diagnosis of pooled records against the same records diagnosed one at a time.
"""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo import cli
from jthermo.data import from_arrays, save_csv
from jthermo.diagnose import diagnose, to_json, write_report
from jthermo.diagnose import mechanisms as M
from jthermo.diagnose import pool as PL
from jthermo.diagnose.checks import as_records, pool_records
from jthermo.errors import DataError
from tests.diagnose.records import record as _record

pytestmark = pytest.mark.filterwarnings("ignore")


def _first_order(u, x0, a, b, ts_level, ts=1.0):
    """$x_{k+1} = e^{-a} x_k + (1 - e^{-a}) / a\\,(b^\\top u_k + a T_s)$, from `x0` (ZOH)."""
    ad = math.exp(-a * ts)
    x = np.empty((u.shape[0], len(x0)))
    s = np.array(x0, float)
    for k in range(u.shape[0]):
        x[k] = s
        s = ad * s + (1.0 - ad) / a * (u[k] @ b.T + a * ts_level)
    return x


@pytest.mark.parametrize("n", [1, 16])
def test_pooled_zone_simulation_restarts_each_record(n):
    """Record by record from its own initial state and level: the recurrence above, per record."""
    rng = np.random.default_rng(n)
    lengths = (37, 52)
    u = rng.uniform(0.2, 0.8, size=(sum(lengths), 1))
    Phi, knots = PL.drift_basis(lengths, 1.0)
    lay = M.make_layout(n, 1, Phi.shape[1], lengths)
    a, b = 1.0 / 40.0, np.array([[0.9]])
    th = M.initial_theta(lay, log_a=math.log(a), log_b=[math.log(0.9)], x0=150.0, ts0=2.0)
    th[lay.sl("x0_rec")] = 170.0
    th[lay.sl("ts0_rec")] = -3.0
    z = {"u": jnp.asarray(u), "ynb": jnp.zeros((u.shape[0], max(n - 1, 1))), "ybar": jnp.zeros(u.shape[0]),
         "events": jnp.zeros(u.shape[0]), "wdev": jnp.zeros(u.shape[0]), "Phi": jnp.asarray(Phi),
         "delay": jnp.asarray(0.0), "u_pad": jnp.asarray(u.mean(axis=0)),
         "u_pads": jnp.asarray(np.stack([u[:37].mean(0), u[37:].mean(0)])), "ts": jnp.asarray(1.0),
         "ts_level": jnp.asarray(145.0), "ts_free": jnp.asarray(1.0), "t_ref": jnp.asarray(160.0)}
    got = np.asarray(PL.simulate_zone(jnp.asarray(th), jnp.asarray(M.baseline_on()), z, lay))
    want = np.concatenate([_first_order(u[:37], [150.0], a, b, 147.0)[:, 0],
                           _first_order(u[37:], [170.0], a, b, 142.0)[:, 0]])
    assert knots == (2, 2) and np.max(np.abs(got - want)) < 1e-9
    # the coupled simulation: every zone the same model, each record its own states and level
    Theta = np.tile(th, (n, 1))
    rec = np.zeros(PL.record_size(n, lay))
    sx, sw, il = PL.record_entries(n, lay, 1)
    rec[:n], rec[sx] = 150.0, 170.0
    rec[2 * n + lay.n_drift], rec[il] = 0.0, -5.0
    f = {k: z[k] for k in ("u", "wdev", "Phi", "delay", "u_pad", "u_pads", "ts", "ts_level", "ts_free", "t_ref")}
    f["events"] = jnp.zeros((u.shape[0], n))
    full = np.asarray(PL.simulate_full(jnp.asarray(Theta), jnp.asarray(M.baseline_on()), f, lay, jnp.asarray(rec)))
    assert np.max(np.abs(full - want[:, None])) < 1e-9


def test_pooled_baseline_recovers_shared_physics_and_each_records_start():
    """Noise-free first-order records of one zone: the shared loss and gain, each record's
    initial temperature and surroundings level, to the optimiser's precision."""
    rng = np.random.default_rng(3)
    lengths = (400, 250)
    a, b = 1.0 / 55.0, np.array([[0.8, 0.3]])
    u = [np.repeat(rng.choice([0.2, 0.8], size=(T // 10, 2)), 10, axis=0) for T in lengths]
    y = np.concatenate([_first_order(u[0], [160.0], a, b, 140.0), _first_order(u[1], [150.0], a, b, 146.0)])
    lay = M.make_layout(1, 2, 4, lengths)
    th0 = M.initial_theta(lay, log_a=math.log(0.01), log_b=[0.0, 0.0], x0=0.0)[None]
    th = PL.fit_baseline(th0, y, np.concatenate(u), lengths, 1.0, 143.0, 1.0, lay)[0]
    assert abs(math.exp(th[lay.sl("log_a")][0]) / a - 1.0) < 1e-4
    assert np.allclose(np.exp(th[lay.sl("log_b")]), b[0], rtol=1e-3)
    assert np.allclose([th[lay.sl("x0")][0], th[lay.sl("x0_rec")][0]], [160.0, 150.0], atol=1e-3)
    assert np.allclose([th[lay.sl("ts0")][0], th[lay.sl("ts0_rec")][0]], [-3.0, 3.0], atol=1e-2)


def test_evidence_shares_add_up_and_name_the_informative_record():
    rng = np.random.default_rng(0)
    e0 = rng.normal(size=(300, 2))
    e1 = e0.copy()
    e1[:200] *= 0.5                       # the candidate helps on the first record only
    sh = PL.evidence_shares(e0, e1, (200, 100))
    assert math.isclose(sum(s["sse_share"] for s in sh), 1.0) and sh[1]["sse_share"] == 0.0
    assert sh[0]["likelihood_ratio"] == pytest.approx(200 * 2 * math.log(4.0), abs=0.01)


def test_records_of_another_plant_are_refused_in_one_line():
    est, val = _record("input_delay", 0, n_est=200, n_val=200)
    other = est.replace(output_names=("a", "b"))
    with pytest.raises(DataError, match="record 2 has other outputs"):
        pool_records([est, other], val, 0.01)
    with pytest.raises(DataError, match="sample times"):
        pool_records([est, est.replace(ts=2.0)], val, 0.01)
    with pytest.raises(DataError, match="list of IOData"):
        as_records([])


@pytest.fixture(scope="module")
def pooled():
    """Two records of one plant with a concealed dead time, of different lengths and inputs,
    and each alone."""
    e1, val = _record("input_delay", 5, n_est=500, n_val=400)
    e2, _ = _record("input_delay", 6, n_est=350, n_val=400)
    mech = ("input_delay", "heater_lag")
    return {"pool": diagnose([e1, e2], val, mechanisms=mech), "one": diagnose(e1, val, mechanisms=mech),
            "two": diagnose(e2, val, mechanisms=mech), "records": (e1, e2, val)}


def test_pooled_records_name_the_truth_at_least_as_surely_as_either(pooled):
    res = pooled["pool"]
    top = res["findings"][0]
    assert top["mechanism"] == "input_delay" and abs(top["parameters"]["delay_s"] - 4.0) <= 0.25
    lr = lambda r: next(c["estimation_lr"] for c in r["candidates"] if c["mechanism"] == "input_delay")
    # the pooled likelihood ratio is about the sum of the records' own (shared parameters)
    assert lr(res) >= max(lr(pooled["one"]), lr(pooled["two"]))
    assert top["confidence"] >= max(r["findings"][0]["confidence"] for r in (pooled["one"], pooled["two"])
                                    if r["findings"] and r["findings"][0]["mechanism"] == "input_delay")
    shares = top["evidence"]["records"]
    assert [s["samples"] for s in shares] == [500, 350]
    assert math.isclose(sum(s["sse_share"] for s in shares), 1.0, rel_tol=1e-9)
    assert all(s["sse_share"] > 0.1 for s in shares)
    assert [r["samples"] for r in res["estimation_records"]] == [500, 350]


def test_pooled_report_and_json(pooled, tmp_path):
    e1, e2, val = pooled["records"]
    js = json.loads(json.dumps(to_json(pooled["pool"])))
    assert len(js["findings"][0]["evidence"]["records"]) == 2
    text = write_report(pooled["pool"], tmp_path / "rep", [e1, e2], val).read_text()
    assert "## Pooled estimation records" in text and "| 2 | 350 |" in text


def test_cli_pools_records_and_needs_no_experiment_for_a_settled_finding(tmp_path, capsys, monkeypatch):
    from jthermo import diagnose as diag

    e1, val = _record("input_delay", 0, n_est=200, n_val=200)
    e2, _ = _record("input_delay", 1, n_est=150, n_val=200)
    paths = [tmp_path / f"{nm}.csv" for nm in ("e1", "e2", "val")]
    for d, p in zip((e1, e2, val), paths):
        save_csv(d, p)
    seen = {}

    def fake(e, v, **kw):
        seen["n"] = len(e)
        return {"verdict": "mismatch", "baseline": {"mean_fit_percent": 90.0},
                "findings": [{"mechanism": "input_delay", "confidence": 0.999, "rivals": [], "uncertain": False}]}

    monkeypatch.setattr(diag, "diagnose", fake)
    out, js = tmp_path / "next.csv", tmp_path / "d.json"
    rc = cli.main(["diagnose", str(paths[0]), str(paths[1]), "--validation", str(paths[2]),
                   "--design-experiment", str(out), "--json", str(js)])
    err = capsys.readouterr()
    assert rc == 0, err.err
    assert seen["n"] == 2 and not out.exists()
    rep = json.loads(js.read_text())
    assert rep["next_step"]["experiment_needed"] is False and "experiment" not in rep
    assert "no experiment needed" in err.out + err.err
    # a record of another plant is one line, exit status 2, nothing written
    bad = tmp_path / "bad.csv"
    save_csv(from_arrays(np.asarray(e1.u)[:, :1], np.asarray(e1.y), 1.0), bad)
    rc = cli.main(["diagnose", str(paths[0]), str(bad), "--validation", str(paths[2]), "--json", str(tmp_path / "x.json")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1 and not (tmp_path / "x.json").exists()
