"""Recoat-free scenarios integrate the printer without the recoat sweep, in fewer sub-steps
(`Printer.discretise(recoat=False)`): the scenarios really have no recoat, dropping the sweep
term changes nothing but the step count, and the error against fine sub-steps stays far below
the sensor noise."""

import dataclasses

import equinox as eqx
import jax
import numpy as np
import pytest

from jthermo.closedloop import REALISTIC_EFFECTS, make_scenario, rollouts
from jthermo.closedloop.engine import RECOAT_FREE_KINDS
from jthermo.control.pi import DiagonalPI
from jthermo.printer import SMOOTH_SUBSTEPS, make_printer

#: the white part of the scenario's measurement noise, °C (make_scenario's noise_std)
NOISE_STD = 0.05


def _printer(substeps=10):
    return make_printer(4, REALISTIC_EFFECTS, seed=0, substeps=substeps)


def _temps(printer, sc):
    ctrl = DiagonalPI.untuned(4, ts=printer.ts)
    return np.asarray(eqx.filter_jit(rollouts)(printer, ctrl, sc).temperature)


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
    sc = make_scenario("tracking", _printer(), 300.0, jax.random.key(5), n_rollouts=2)
    full = dataclasses.replace(sc, kind="custom")     # another label: the full integration
    now = _temps(_printer(), sc)
    # the sweep term is exactly zero without a recoat: same sub-steps, same run
    same = _temps(_printer(SMOOTH_SUBSTEPS), full)
    np.testing.assert_allclose(now, same, rtol=0, atol=1e-10)
    # against 50 sub-steps: the integration error is far below the measurement noise
    fine = _temps(_printer(50), full)
    assert np.max(np.abs(now - fine)) < 0.1 * NOISE_STD
