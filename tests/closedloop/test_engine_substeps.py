"""`run` integrates the printer in recoat-free scenarios without the recoat sweep, in fewer
sub-steps (`rollout_metrics(..., recoat=False)`, `Printer.discretise(recoat=False)`): the
scenarios really have no recoat, dropping the sweep term changes nothing but the step count,
and the error against fine sub-steps stays far below the sensor noise."""


import equinox as eqx
import jax
import numpy as np
import pytest

from jthermo.closedloop import REALISTIC_EFFECTS, make_scenario, rollout_metrics, run
from jthermo.closedloop.engine import RECOAT_FREE_KINDS, run_scenario
from jthermo.control.pi import DiagonalPI
from jthermo.printer import SMOOTH_SUBSTEPS, make_printer


def _printer(substeps=10):
    return make_printer(4, REALISTIC_EFFECTS, seed=0, substeps=substeps)


def _metrics(printer, sc, recoat=True):
    ctrl = DiagonalPI.untuned(4, ts=printer.ts)
    out = eqx.filter_jit(rollout_metrics)(printer, ctrl, sc, recoat=recoat)
    return np.array([out[k] for k in ("mse_true", "mse", "max_abs_error_C", "effort")])


@pytest.mark.parametrize("kind", RECOAT_FREE_KINDS)
def test_recoat_free_kinds_draw_no_recoat(kind):
    sc = make_scenario(kind, _printer(), 300.0, jax.random.key(3), n_rollouts=2)
    assert not np.any(np.asarray(sc.d.recoat))


def test_sub_steps_by_scenario():
    pr = _printer()
    assert pr.discretise().m == pr.substeps == 10
    assert pr.discretise(recoat=False).m == SMOOTH_SUBSTEPS
    linear = make_printer(4, ["lateral_conduction", "recoat_cooling"], seed=0)
    assert linear.discretise(recoat=False).m == 1


def test_recoat_free_run_matches_fine_steps():
    # tracking (preheat: benchmarks/results/simulate_substeps.md)
    sc = run_scenario("tracking", _printer(), 300.0, jax.random.key(5), 2)  # run's noise
    now = _metrics(_printer(), sc, recoat=False)
    # the sweep term is exactly zero without a recoat: same sub-steps, same run
    np.testing.assert_allclose(now, _metrics(_printer(SMOOTH_SUBSTEPS), sc), rtol=1e-10)
    # against 50 sub-steps: the figures within 1e-3 relative (MSE ~0.1-1 °C^2 here)
    np.testing.assert_allclose(now, _metrics(_printer(50), sc), rtol=1e-3)
    # and `run` takes this path in tracking (its MSE is the mean over the rollouts)
    out = run("tracking", DiagonalPI.untuned(4, ts=1.0), _printer(), rollouts=2, duration=300.0,
              seed=5)
    np.testing.assert_allclose(out["metrics"]["mse_true"], np.mean(now[0]), rtol=1e-10)
