"""`tune_report`'s comparison with every classical design (`best_classical`) and its robustness
section, with the simulations replaced by a recorded cost per controller (fast: the logic)."""

import types

import numpy as np

import jthermo.tune.report as report
from jthermo.control import LQG, DiagonalPI, ScheduleFF
from jthermo.tune import CLASSICAL


def test_best_classical_is_the_cheapest_design_on_the_same_seeds(monkeypatch):
    calls = []

    def fake_evaluate(c, plant, kind, seeds, **kw):
        calls.append((id(c), id(plant), tuple(seeds)))
        if isinstance(c, ScheduleFF):
            cost = 0.5
        elif isinstance(c, LQG):
            cost = 0.8
        elif isinstance(c, DiagonalPI):
            cost = 1.0 if float(c.kp[0]) == 0.15 else 2.0     # untuned, lambda
        else:
            cost = 3.0
        sc = {"cost": cost, "mse": cost / 2}
        return {"cost": cost, "scenarios": {k: sc for k in report.SCENARIOS}}

    def fake_tune(start, plant, **kw):
        return types.SimpleNamespace(controller=start, start_cost=1.0, tuned_cost=1.0, guard={},
                                     history=[1.0], seconds=0.0)

    monkeypatch.setattr(report, "evaluate", fake_evaluate)
    monkeypatch.setattr(report, "tune", fake_tune)
    rep = report.tune_report("lqg_ff", zones=2, steps=1, rollouts=1, ensemble=0)
    assert set(rep["classical_costs"]) == set(CLASSICAL)
    assert rep["best_classical"] == "lqg" and rep["best_classical_cost"] == 0.8
    assert rep["tuned_cost"] == 0.5 and rep["lambda_pi_cost"] == 2.0
    assert np.isclose(rep["improvement_vs_best_classical_percent"], 100 * (1 - 0.5 / 0.8))
    assert np.isclose(rep["improvement_percent"], 75.0)
    ch = rep["changed_powder"]
    assert ch["powder"] == "PA11" and ch["best_classical"] == "lqg"
    # every comparison on the held-out seed only
    assert {s for _, _, s in calls} == {(report.HELD_OUT,)}
    rb = rep["robustness"]
    assert set(rb["ms"]) == {"tuned", "start", "best_classical"}
    assert all(1.0 <= m < 2.0 for m in rb["ms"].values()) and all(rb["stable"].values())
    assert rb["gain_plus_20_cost"]["tuned"] == 0.5 and rb["gain_minus_20_cost"]["best_classical"] == 0.8
    # no guard record from the (fake) tuning: the returned loop is judged against ms_max
    msc = rep["ms_constraint"]
    assert msc["ms_max"] == 2.0 and msc["satisfied"] is True
    assert np.isclose(msc["chosen_ms"], rb["ms"]["tuned"])
