"""The lean metrics (accumulated inside the scan, no trajectory stored) against the dense ones
(`metrics` and `cost` of the stored trajectories): every figure, every rollout, to 1e-10."""

import equinox as eqx
import jax
import numpy as np
import pytest

from jthermo.closedloop import (
    METRICS,
    cost,
    make_scenario,
    metrics,
    rollout_metrics,
    rollouts,
    run,
    simulate,
    simulate_metrics,
)
from jthermo.closedloop.engine import run_scenario
from jthermo.control.pi import DiagonalPI
from jthermo.errors import ConfigError
from jthermo.printer import make_printer

EFFECTS = ["lateral_conduction", "radiative_loss", "recoat_cooling", "laser_exposure",
           "sensor_noise", "ambient_variation"]


def _dense(plant, ctrl, sc, weights=None):
    traj = eqx.filter_jit(rollouts)(plant, ctrl, sc)
    per = metrics(traj, sc, per_rollout=True)
    per["cost"] = np.asarray(jax.vmap(lambda t, s: cost(t, s, weights))(traj, sc))
    return per


def _assert_same(lean, dense):
    assert set(lean) == set(METRICS) | {"cost"}
    for k in lean:
        np.testing.assert_allclose(np.asarray(lean[k]), dense[k], rtol=1e-10, atol=1e-10,
                                   err_msg=k)


@pytest.mark.parametrize(("kind", "zones", "duration"), [
    ("tracking", 4, 200.0),     # step: overshoot, settling, time to ready
    ("print", 4, 300.0),        # recoat and laser events, neighbour differences
    ("preheat", 2, 20.0),       # a cold start that does not reach the window in 20 s
    ("powder", 1, 150.0),       # one zone: no neighbours, no uniformity term
])
def test_lean_metrics_equal_dense_metrics(kind, zones, duration):
    plant = make_printer(zones, EFFECTS, seed=0)
    ctrl = DiagonalPI.untuned(zones)
    sc = make_scenario(kind, plant, duration, 3, n_rollouts=3)
    weights = {"tracking": 1.0, "uniformity": 0.5, "effort": 2.0, "window": 0.3}
    lean = eqx.filter_jit(rollout_metrics)(plant, ctrl, sc, weights)
    dense = _dense(plant, ctrl, sc, weights)
    _assert_same(lean, dense)
    if kind == "preheat":   # never inside: both times are the run length
        np.testing.assert_array_equal(lean["settling_time_s"], sc.n_samples * sc.ts)
        np.testing.assert_array_equal(lean["time_to_ready_s"], sc.n_samples * sc.ts)
    if kind == "tracking":  # the step settles inside the run, after the first sample
        assert 0 < float(lean["settling_time_s"].min()) < sc.n_samples * sc.ts
    one = jax.tree.map(lambda a: a[1], sc)
    single = eqx.filter_jit(simulate_metrics)(plant, ctrl, one, weights)
    _assert_same(single, {k: v[1] for k, v in dense.items()})


def test_run_reports_the_dense_figures_and_lean_path_checks_batching():
    plant = make_printer(3, EFFECTS, seed=1)
    ctrl = DiagonalPI.untuned(3)
    out = run("ensemble", ctrl, plant, rollouts=2, duration=120.0, seed=5)
    sc = run_scenario("ensemble", plant, 120.0, jax.random.key(5), 2)   # with run's noise
    traj = eqx.filter_jit(rollouts)(plant, ctrl, sc)
    dense = metrics(traj, sc)
    assert set(out["metrics"]) == set(METRICS)
    for k, v in dense.items():
        assert out["metrics"][k] == pytest.approx(v, rel=1e-10, abs=1e-10), k
    assert out["cost"] == pytest.approx(float(cost(traj, sc)), rel=1e-10)
    with pytest.raises(ConfigError, match="leading rollout axis"):
        rollout_metrics(plant, ctrl, jax.tree.map(lambda a: a[0], sc))
    with pytest.raises(ConfigError, match="batched scenario"):
        simulate(plant, ctrl, sc)


def test_lean_metrics_on_fitted_model_plants():
    """The grey-box bed (its own step) and its state space (the linear adapter) as plants,
    under the reference printer's ensemble scenario: lean equals dense."""
    from jthermo.models import BedModel

    pr = make_printer(3, ["laser_exposure", "recoat_cooling"], seed=2)
    par = pr.linear_bed_parameters()
    bed = BedModel.from_physical(*(np.asarray(par[k]) for k in ("capacity", "loss", "gain")),
                                 ts=1.0)
    ctrl = DiagonalPI.untuned(3)
    for plant in (bed, bed.to_statespace()):
        sc = make_scenario("ensemble", plant, 150.0, 6, n_rollouts=2, reference=pr)
        _assert_same(eqx.filter_jit(rollout_metrics)(plant, ctrl, sc), _dense(plant, ctrl, sc))
