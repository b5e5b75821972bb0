"""Metric names mean what they say: `mean_input` is the mean input, `mean_sq_input_change` is
the cost's `effort` term before its weight, and the old `effort` key (the mean input) is still
reported for one release."""

import equinox as eqx
import numpy as np
import pytest

from jthermo.closedloop import cost, make_scenario, metrics, rollout_metrics, rollouts
from jthermo.closedloop.scoring import DEPRECATED_METRICS
from jthermo.control.pi import DiagonalPI
from jthermo.printer import make_printer


def test_input_metrics_are_named_by_what_they_measure():
    plant = make_printer(2, ["lateral_conduction"], seed=0)
    ctrl = DiagonalPI.untuned(2)
    sc = make_scenario("tracking", plant, 120.0, 1, n_rollouts=2)
    traj = eqx.filter_jit(rollouts)(plant, ctrl, sc)
    u = np.asarray(traj.u)                                      # (B, T, nu)
    du = np.diff(u, axis=1)
    per = metrics(traj, sc, per_rollout=True)
    lean = eqx.filter_jit(rollout_metrics)(plant, ctrl, sc)
    for m in (per, lean):
        np.testing.assert_allclose(m["mean_input"], u.mean(axis=(1, 2)), rtol=1e-12)
        np.testing.assert_allclose(m["input_variation"], np.abs(du).mean(axis=(1, 2)), rtol=1e-12)
        np.testing.assert_allclose(m["mean_sq_input_change"], (du ** 2).mean(axis=(1, 2)),
                                   rtol=1e-10)
        for old, new in DEPRECATED_METRICS.items():
            np.testing.assert_array_equal(m[old], m[new])
    # the metric is the cost's effort term: only that term's weight on, the cost equals it
    only_effort = {"tracking": 0.0, "uniformity": 0.0, "effort": 1.0, "window": 0.0}
    assert float(cost(traj, sc, only_effort)) == pytest.approx(
        float(np.mean(per["mean_sq_input_change"])), rel=1e-10)
    assert float(np.mean(per["mean_sq_input_change"])) > 0.0
