"""`tune_report`'s comparison with every classical design (`best_classical`) and its robustness
section, with the simulations replaced by a recorded cost per controller (fast: the logic)."""

import types

import jax
import numpy as np

import jthermo.tune.report as report
from jthermo.control import LQG, DiagonalPI, ScheduleFF
from jthermo.tune import CLASSICAL


def test_best_classical_is_the_cheapest_design_on_the_same_seeds(monkeypatch):
    calls = []
    make = report.make_scenario

    def fake_scenario(kind, plant, duration, key, **kw):
        calls.append(int(jax.random.key_data(key)[-1]))
        return make(kind, plant, 30.0, key, **kw)

    def fake_terms(c, batch, weights):
        if isinstance(c, ScheduleFF):
            cost = 0.5
        elif isinstance(c, LQG):
            cost = 0.8
        elif isinstance(c, DiagonalPI):
            cost = 1.0 if float(c.kp[0]) == 0.15 else 2.0     # untuned, lambda
        else:
            cost = 3.0
        n = sum(len(g.index) for g in batch)
        return np.tile([cost, cost / 2], (n, 1))

    def fake_tune(start, plant, **kw):
        return types.SimpleNamespace(controller=start, start_cost=1.0, tuned_cost=1.0, guard={},
                                     history=[1.0], seconds=0.0, method="adam",
                                     evaluations=1)

    monkeypatch.setattr(report, "make_scenario", fake_scenario)
    monkeypatch.setattr(report, "batch_terms", fake_terms)
    monkeypatch.setattr(report, "tune", fake_tune)
    rep = report.tune_report("lqg_ff", zones=2, steps=1, rollouts=1, ensemble=0)
    assert set(rep["classical_costs"]) == set(CLASSICAL)
    assert rep["best_classical"] == "lqg" and np.isclose(rep["best_classical_cost"], 0.8)
    assert np.isclose(rep["tuned_cost"], 0.5) and np.isclose(rep["lambda_pi_cost"], 2.0)
    assert np.isclose(rep["improvement_vs_best_classical_percent"], 100 * (1 - 0.5 / 0.8))
    assert np.isclose(rep["improvement_percent"], 75.0)
    ch = rep["changed_powder"]
    assert ch["powder"] == "PA11" and ch["best_classical"] == "lqg"
    # every comparison on the held-out seed only
    assert set(calls) == {report.HELD_OUT}
    rb = rep["robustness"]
    assert set(rb["ms"]) == {"tuned", "start", "best_classical"}
    assert all(1.0 <= m < 2.0 for m in rb["ms"].values()) and all(rb["stable"].values())
    assert np.isclose(rb["gain_plus_20_cost"]["tuned"], 0.5)
    assert np.isclose(rb["gain_minus_20_cost"]["best_classical"], 0.8)
    # no guard record from the (fake) tuning: the returned loop is judged against ms_max
    msc = rep["ms_constraint"]
    assert msc["ms_max"] == 2.0 and msc["satisfied"] is True
    assert np.isclose(msc["chosen_ms"], rb["ms"]["tuned"])


def test_held_out_terms_equal_evaluate():
    """The lean held-out path (one batch of every plant, scenario and seed) gives `evaluate`'s
    cost and mse per scenario."""
    plant = report.make_printer(2, report.REALISTIC_EFFECTS, seed=0)
    model = report.printer_model(plant)
    ctrls = {"pi": report.design("pi_lambda", model)}
    kw = {"rollouts": 2, "duration": 30.0}
    got = report.held_out_terms(ctrls, {"p": plant}, (7, 8), **kw)
    for name, c in ctrls.items():
        ref = report.evaluate(c, plant, report.SCENARIOS, (7, 8), **kw)
        assert np.isclose(got[name]["p"]["cost"], ref["cost"], rtol=1e-9)
        for k in report.SCENARIOS:
            for q in ("cost", "mse"):
                assert np.isclose(got[name]["p"]["scenarios"][k][q], ref["scenarios"][k][q],
                                  rtol=1e-9), (name, k, q)


def test_evaluate_fitted_model_equals_plain_path():
    """`evaluate` on a fitted model (whose scenarios check their envelope in Python, so they are
    not built inside a compiled program) gives the cost and mse of the plain rollouts."""
    from jthermo.closedloop import MODEL_KINDS, cost, make_scenario, metrics, rollouts
    from jthermo.identify.fit import fit
    from jthermo.printer import generate

    plant = report.make_printer(2, (), seed=0)
    model = fit(generate(plant, "prbs", 600.0, seed=0), "ss", (2,), seed=0, n_starts=1).model
    ctrl = report.design("pi_lambda", model)
    kind = MODEL_KINDS[0]
    got = report.evaluate(ctrl, model, kind, (7,), rollouts=2, duration=120.0)
    sc = make_scenario(kind, model, 120.0, jax.random.key(7), n_rollouts=2)
    traj = rollouts(model, ctrl, sc)
    assert np.isclose(got["cost"], float(cost(traj, sc)), rtol=1e-9)
    assert np.isclose(got["scenarios"][kind]["mse"], metrics(traj, sc)["mse"], rtol=1e-9)


def test_evaluate_compiles_one_program_for_every_kind():
    """`evaluate` runs every scenario kind through one compiled program (the kind is a label
    no rollout or score reads): after a first kind, the others lower nothing, and each kind's
    figures are bit for bit those of the labelled scenario."""
    import collections

    from jax import monitoring

    from jthermo.closedloop import compiled_make_scenario

    plant = report.make_printer(2, report.REALISTIC_EFFECTS, seed=0)
    ctrl = report.design("pi_decoupled", report.printer_model(plant))
    kw = {"rollouts": 2, "duration": 37.0}          # shapes no other test uses
    kinds = tuple(report.SCENARIOS)
    report.evaluate(ctrl, plant, kinds[0], (7,), **kw)
    for k in kinds[1:]:                              # the scenario builders, compiled apart
        compiled_make_scenario()(k, plant, kw["duration"], jax.random.key(7), n_rollouts=2)
    events = collections.Counter()

    def count(name, _secs, **_):
        events[name] += 1

    monitoring.register_event_duration_secs_listener(count)
    try:
        got = report.evaluate(ctrl, plant, kinds, (7,), **kw)
    finally:
        monitoring.unregister_event_duration_listener(count)
    assert events["/jax/core/compile/jaxpr_to_mlir_module_duration"] == 0
    for k in kinds:
        sc = compiled_make_scenario()(k, plant, kw["duration"], jax.random.key(7), n_rollouts=2)
        assert sc.kind == k
        J, m = jax.device_get(report.quick_evaluate()[0](plant, ctrl, sc, None))
        assert got["scenarios"][k]["cost"] == float(J)
        assert got["scenarios"][k]["mse"] == float(m["mse"])
