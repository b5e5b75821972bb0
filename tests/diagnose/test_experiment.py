"""The designed experiment (`jthermo.diagnose.experiment`) and `jthermo diagnose --design-experiment`.

Two hand-built one-zone models (lamp lag 4 s, dead time 3 s) stand in for the diagnosis' fitted
rivals, so every test runs without a diagnosis fit.
"""

import json
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo import cli
from jthermo.data import from_arrays, load_csv, save_csv
from jthermo.diagnose import experiment as X
from jthermo.diagnose import mechanisms as M
from jthermo.errors import ConfigError

pytestmark = pytest.mark.filterwarnings("ignore")

T = 120
TS = 145.0                          # °C surroundings
A_RATE, B_GAIN = 1.0 / 60.0, 0.97   # 1/s, °C/s per unit input: about 29 K above TS at u = 0.5


def _theta(lay, **mech):
    th = M.initial_theta(lay, log_a=math.log(A_RATE), log_b=[math.log(B_GAIN)], x0=TS + 29.0)
    for k, v in mech.items():
        th[lay.sl(k)] = v
    return th[None, :]


def _result(rivals=("input_delay",), top="heater_lag"):
    lay = M.make_layout(1, 1, M.n_drift_knots(T, 1.0))
    models = {"theta": {"baseline": _theta(lay), "heater_lag": _theta(lay, log_tauh=math.log(4.0)),
                        "input_delay": _theta(lay)},
              "layout": lay, "level": TS, "ts_free": 0.0, "t_ref": TS + 29.0, "delay": 3.0,
              "measured_ambient": False, "period": 0, "zone_phase": [0], "inputs_left_out": []}
    return {"findings": [{"mechanism": top, "rivals": list(rivals)}], "candidates": [],
            "_models": models, "_arrays": {"yhat_augmented": np.full((T, 1), TS + 29.0)}}


# compiled once for the module (eager, a call compiles each of its operations on its own)
_separations = eqx.filter_jit(X.separations)
_jacobians = eqx.filter_jit(X.nuisance_jacobians)


def _records(seed=0):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.choice([0.3, 0.7], size=(T // 10, 1)), 10, axis=0)
    y = TS + 29.0 + 0.05 * rng.standard_normal((T, 1))
    return from_arrays(u, y, 1.0), from_arrays(u[::-1], y, 1.0)


def test_objective_gradient_matches_central_differences():
    res = _result()
    hold = 5
    ctx = X.rival_context(res["_models"], ("heater_lag", "input_delay", "baseline"), T, 1.0,
                          np.array([0.5]), np.array([TS + 29.0]))
    Q = jnp.asarray(X.nuisance_basis(T, 1.0, drift=False))
    lo, hi, sig = jnp.array([0.3]), jnp.array([0.7]), jnp.array([0.05])
    f = jax.jit(lambda z: X.objective(X.squash(z, lo, hi, hold, T), ctx, Q, sig))
    z = jnp.asarray(np.random.default_rng(3).normal(size=(T // hold, 1)))
    g = np.asarray(jax.jit(jax.grad(f))(z))
    eps = 1e-6
    for idx in [(0, 0), (7, 0), (15, 0), (23, 0)]:
        dz = jnp.zeros_like(z).at[idx].set(eps)
        fd = (float(f(z + dz)) - float(f(z - dz))) / (2 * eps)
        assert abs(g[idx] - fd) <= 1e-5 * max(1.0, np.max(np.abs(g)))
    assert np.max(np.abs(g)) > 0
    u = X.squash(z, lo, hi, hold, T)
    S = np.asarray(_separations(u, ctx, Q, sig))
    assert S.shape == (3,) and np.all(S > 0) and np.isclose(float(f(z)), np.sum(np.log(S)))


def test_nuisance_criterion_removes_an_initial_state_transient_and_has_its_gradient():
    # two baselines that differ only in their start: a refit of the new record's initial state
    # absorbs the whole gap (the former constant-only span does not); a lag against a delay
    # keeps a gap, whose gradient matches central differences (the sensitivities of a model
    # linear in its states do not depend on the input)
    res = _result()
    ctx = X.rival_context(res["_models"], ("baseline", "baseline"), T, 1.0, np.array([0.5]),
                          np.array([TS + 29.0]))
    ctx = (*ctx[:3], ctx[3].at[1, 0].add(30.0), *ctx[4:])   # decays over the warm-up to 0.2 °C
    sig = jnp.array([0.05])
    u = jnp.asarray(_records()[0].u)
    Q0 = jnp.asarray(X.nuisance_basis(T, 1.0, drift=False))
    raw = float(_separations(u, ctx, Q0, sig)[0])
    assert raw > 50.0 and float(_separations(u, ctx, None, sig)[0]) < 1e-6 * raw
    ctx = X.rival_context(res["_models"], ("heater_lag", "input_delay"), T, 1.0, np.array([0.5]),
                          np.array([TS + 29.0]))
    lo, hi, hold = jnp.array([0.3]), jnp.array([0.7]), 5
    f = jax.jit(lambda z: X.objective(X.squash(z, lo, hi, hold, T), ctx, None, sig))
    z = jnp.asarray(np.random.default_rng(4).normal(size=(T // hold, 1)))
    g = np.asarray(jax.jit(jax.grad(f))(z))
    eps = 1e-6
    for idx in [(0, 0), (9, 0), (20, 0)]:
        dz = jnp.zeros_like(z).at[idx].set(eps)
        fd = (float(f(z + dz)) - float(f(z - dz))) / (2 * eps)
        assert abs(g[idx] - fd) <= 1e-5 * max(1.0, np.max(np.abs(g)))
    J = np.asarray(_jacobians(u, ctx))
    assert J.shape[:2] == (2, T) and np.all(J[:, :, 1] == 0.0)       # no body: its state is not re-estimated
    assert np.allclose(J[:, 1:, 0] / J[:, :-1, 0], math.exp(-A_RATE), rtol=1e-6)   # e^{-a t}


def test_nuisance_projection_removes_constant_and_drift():
    Q = X.nuisance_basis(900, 1.0, drift=True)
    t = np.arange(900.0)
    d = 2.0 + 0.01 * t                        # an offset and a ramp: a drift absorbs both
    assert np.allclose(d - Q @ (Q.T @ d), 0.0, atol=1e-9)
    Q0 = X.nuisance_basis(900, 1.0, drift=False)
    assert np.allclose(Q0.T @ Q0, np.eye(Q0.shape[1]))
    assert np.linalg.norm(d - Q0 @ (Q0.T @ d)) > 1.0


@pytest.fixture(scope="module")
def free_design():
    """The design without a temperature limit (two tests read it; neither changes it)."""
    est, val = _records()
    return X.design_experiment(_result(), est, val, hold=5, n_steps=40, seed=2)


def test_design_beats_its_prbs_within_limits_and_is_deterministic(free_design):
    est, val = _records()
    d1 = free_design
    d2 = X.design_experiment(_result(), est, val, hold=5, n_steps=40, seed=2)
    u = d1["u"]
    assert u.shape == (T, 1) and np.array_equal(u, d2["u"])
    # both starts' optimisation, not only the input kept (the PRBS's seed, the random start's)
    assert np.array_equal(d1["history"], d2["history"])
    assert np.all(u >= 0.3 - 1e-12) and np.all(u <= 0.7 + 1e-12)
    assert np.all(u.reshape(-1, 5)[:, :1] == u.reshape(-1, 5))          # held over 5 samples
    assert d1["separation_designed"] > d1["separation_prbs"] > 0
    assert d1["rivals"] == ["heater_lag", "input_delay"]
    assert list(d1["pair_separations"]) == ["heater_lag/input_delay"]
    js = X.to_json(d1, "x.csv")
    assert js["separation_ratio"] > 1 and js["path"] == "x.csv" and json.dumps(js)


def test_no_rival_designs_against_the_runner_up_and_the_baseline_and_says_so():
    assert X.rival_set(_result(rivals=())) == (("heater_lag", "baseline"),
                                              "no rival: the top finding against the baseline")
    res = _result(rivals=())
    res["candidates"] = [{"mechanism": "heater_lag", "val_reduction": 0.3},
                         {"mechanism": "radiative_loss", "val_reduction": -0.01},
                         {"mechanism": "input_delay", "val_reduction": 0.2}]
    assert X.rival_set(res)[0] == ("heater_lag", "input_delay", "baseline")
    # the runner-up need not be told from the baseline: that pair is left out of the objective
    assert X.pair_mask(("heater_lag", "input_delay", "baseline")).tolist() == [1.0, 1.0, 0.0]
    assert X.pair_mask(("heater_lag", "input_delay", "radiative_loss")).tolist() == [1.0, 1.0, 1.0]
    nothing = {"findings": [], "candidates": [{"mechanism": "heater_lag", "val_reduction": 0.01},
                                              {"mechanism": "input_delay", "val_reduction": 0.02}]}
    assert X.rival_set(nothing)[0] == ("input_delay", "heater_lag", "baseline")
    nothing["candidates"][0]["val_reduction"] = -0.01
    assert X.rival_set(nothing)[0] == ("input_delay", "baseline")
    nothing["candidates"][1]["val_reduction"] = -0.02
    assert X.rival_set(nothing)[0] == ("heater_lag", "baseline")


def test_a_temperature_limit_keeps_every_model_below_it(free_design):
    est, val = _records()
    free = free_design
    cap = max(free["max_predicted"]) - 1.5          # the unconstrained design goes 1.5 °C above it
    d = X.design_experiment(_result(), est, val, hold=5, n_steps=40, seed=2, y_max=cap)
    assert free["y_max"] is None and free["within_y_max"]
    assert d["within_y_max"] and max(d["max_predicted"]) <= cap + X.OVER_TOL
    assert np.max(d["predictions"]) <= cap + X.OVER_TOL < np.max(free["predictions"]) and d["separation_designed"] > 0
    with pytest.raises(ConfigError, match="y_max must be finite"):
        X.design_experiment(_result(), est, val, hold=5, n_steps=40, seed=2, y_max=float("nan"))


def test_an_idle_input_is_held_at_its_recorded_value():
    est, val = _records()
    u2 = np.column_stack([est.u[:, 0], np.full(T, 0.25)])
    v2 = np.column_stack([val.u[:, 0], np.full(T, 0.25)])
    est2 = est.replace(u=u2, input_names=("1", "2"))
    val2 = val.replace(u=v2, input_names=("1", "2"))
    res = _result()
    res["_models"]["inputs_left_out"] = ["2"]
    d = X.design_experiment(res, est2, val2, hold=5, n_steps=40, seed=2)    # compiled above
    assert d["u"].shape == (T, 2) and np.all(d["u"][:, 1] == 0.25) and np.ptp(d["u"][:, 0]) > 0
    assert d["limits"]["inputs"] == ["1"] and d["record"].n_inputs == 2


def test_bad_arguments_are_one_line_config_errors():
    est, val = _records()
    with pytest.raises(ConfigError, match="before `to_json`"):
        X.design_experiment({"findings": []}, est, val)
    with pytest.raises(ConfigError, match="hold must be a positive integer"):
        X.design_experiment(_result(), est, val, hold=0)
    with pytest.raises(ConfigError, match="u_max > u_min"):
        X.design_experiment(_result(), est, val, u_min=0.5, u_max=0.5)


def test_cli_writes_the_design_and_refuses_a_bad_path(tmp_path, capsys, monkeypatch):
    from jthermo import diagnose as diag

    est, val = _records()
    pe, pv = tmp_path / "est.csv", tmp_path / "val.csv"
    save_csv(est, pe)
    save_csv(val, pv)
    monkeypatch.setattr(diag, "diagnose", lambda e, v, **kw: {
        "verdict": "mismatch", "baseline": {"mean_fit_percent": 90.0}, **_result()})
    out, js = tmp_path / "next.csv", tmp_path / "d.json"
    rc = cli.main(["diagnose", str(pe), "--validation", str(pv), "--design-experiment", str(out),
                   "--design-hold", "5", "--design-max-temp", "400", "--json", str(js)])
    err = capsys.readouterr().err
    assert rc == 0, err
    rec = load_csv(out)
    assert rec.n_samples == T and rec.input_names == est.input_names and rec.output_names == est.output_names
    exp = json.loads(js.read_text())["experiment"]
    assert exp["rivals"] == ["heater_lag", "input_delay"] and exp["path"] == str(out)
    assert exp["separation_designed"] >= exp["separation_prbs"]
    rc = cli.main(["diagnose", str(pe), "--validation", str(pv), "--design-experiment", str(tmp_path)])
    err = capsys.readouterr().err
    assert rc == 2 and "--design-experiment" in err and len(err.strip().splitlines()) == 1
    rc = cli.main(["diagnose", str(pe), "--validation", str(pv), "--design-experiment", str(out),
                   "--design-hold", "0"])
    assert rc == 2 and "--design-hold" in capsys.readouterr().err

    def never(*a, **kw):
        raise AssertionError("the diagnosis ran before the options were checked")

    monkeypatch.setattr(diag, "diagnose", never)
    rc = cli.main(["diagnose", str(pe), "--validation", str(pv), "--design-experiment", str(out),
                   "--design-duration", "15", "--design-hold", "10"])
    err = capsys.readouterr().err
    assert rc == 2 and "two --design-hold" in err and len(err.strip().splitlines()) == 1


def test_report_has_the_next_experiment(tmp_path):
    from jthermo.diagnose import write_report

    exp = {"rivals": ["heater_lag", "input_delay"], "why": "the top finding and its rivals",
           "separation_designed": 60.0, "separation_prbs": 27.0, "duration_s": 600.0,
           "limits": {"inputs": ["1"], "u_min": [0.3], "u_max": [0.7]}, "path": "next.csv"}
    res = {"verdict": "no_significant_mismatch", "findings": [], "experiment": exp,
           "baseline": {"model": "greybox", "mean_fit_percent": 90.0, "fit_percent": [90.0]}}
    est, val = _records()
    text = write_report(res, tmp_path, est, val).read_text()
    assert "## Next experiment" in text and "`heater_lag`, `input_delay`" in text and "next.csv" in text
    assert json.loads((tmp_path / "diagnosis.json").read_text())["experiment"]["separation_prbs"] == 27.0


def test_only_the_drift_model_re_estimates_a_drift_under_the_nuisance_criterion():
    # the diagnosis re-estimates a surroundings drift on a new record for `ambient_variation`
    # alone: under `nuisance` a slow gap the other models leave counts as separation; the former
    # `nuisance_drift` let every model follow a drift, so a gap can only shrink under it
    res = _result()
    names = ("heater_lag", "input_delay")
    u = jnp.asarray(_records()[0].u)
    sig = jnp.array([0.05])
    ctx = X.rival_context(res["_models"], names, T, 1.0, np.array([0.5]), np.array([TS + 29.0]))
    ctx_d = X.rival_context(res["_models"], names, T, 1.0, np.array([0.5]), np.array([TS + 29.0]),
                            drift_all=True)
    kr = M.n_drift_knots(T, 1.0)
    assert np.all(np.asarray(ctx[6]["mask"])[:, 2:2 + kr] == 0.0)
    assert np.all(np.asarray(ctx_d[6]["mask"])[:, 2:2 + kr] == 1.0)
    ctx_a = X.rival_context(res["_models"] | {"theta": {**res["_models"]["theta"],
                                                        "ambient_variation": res["_models"]["theta"]["baseline"]}},
                            ("ambient_variation", "baseline"), T, 1.0, np.array([0.5]), np.array([TS + 29.0]))
    assert np.asarray(ctx_a[6]["mask"])[:, 2:2 + kr].tolist() == [[1.0] * kr, [0.0] * kr]
    s, s_d = (float(_separations(u, c, None, sig)[0]) for c in (ctx, ctx_d))
    assert s > 0 and s >= s_d * (1 - 1e-9) and s > 1.01 * s_d
    # ... when the drift model is one of the rivals; when it is not, every model follows a drift
    # (a drift candidate the design does not model would take a slow gap)
    assert X.drift_for_all(names) and X.drift_for_all(("ambient_variation", "heat_accumulation"), "nuisance_drift")
    assert not X.drift_for_all(("heat_accumulation", "ambient_variation", "baseline"))
