"""`models.plausibility.coverage`: the steady states' extremes over the recorded box, checked
against the brute-force enumeration of the box's corners (the steady output is linear in the
inputs and signals, so its extremes lie at corners)."""

import itertools

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

from jthermo.models import StateSpace, steady_output  # noqa: E402
from jthermo.data import from_arrays  # noqa: E402
from jthermo.models.plausibility import coverage, heat_check  # noqa: E402


def _model(n, nw, seed):
    rng = np.random.default_rng(seed)
    A = np.diag(rng.uniform(0.5, 0.95, n)) + 0.02 * rng.standard_normal((n, n))
    B = rng.standard_normal((n, n))          # gains of either sign: corners matter
    Bw = rng.standard_normal((n, nw))
    return StateSpace(A, B, np.eye(n), ts=1.0, Bw=Bw, u0=rng.uniform(0, 1, n),
                      w0=rng.uniform(20, 25, nw), y0=rng.uniform(20, 60, n))


def _corners(model, ur, wr):
    pick = lambda bits, box: np.array([box[b, j] for j, b in enumerate(bits)])  # noqa: E731
    ys = [steady_output(model, pick(bu, ur), pick(bw, wr) if wr.shape[1] else None)
          for bu in itertools.product((0, 1), repeat=ur.shape[1])
          for bw in itertools.product((0, 1), repeat=wr.shape[1])]
    return np.min(ys, 0), np.max(ys, 0)


@pytest.mark.parametrize("n,nw", [(1, 0), (3, 1), (5, 2)])
def test_coverage_extremes_are_the_box_corners(n, nw):
    model = _model(n, nw, seed=n)
    ur = np.stack([np.zeros(n), np.linspace(0.3, 1.0, n)])
    wr = np.stack([np.full(nw, 18.0), np.full(nw, 26.0)])
    lo, hi = _corners(model, ur, wr)
    got = coverage(model, ur, wr if nw else None, np.stack([lo, hi]))
    np.testing.assert_allclose(got["steady_min"], lo, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got["steady_max"], hi, rtol=0, atol=1e-9)
    assert got["covered"]


def test_coverage_sees_every_input_at_many_zones():
    """At 16 heaters every input's range counts (a corner loop capped at 12 inputs would miss
    the last four): the range a 16th heater alone reaches is covered, one beyond it is not."""
    n = 16
    model = StateSpace(0.9 * np.eye(n), np.eye(n), np.eye(n), ts=1.0,
                       u0=np.zeros(n), y0=np.full(n, 20.0))
    ur = np.stack([np.zeros(n), np.ones(n)])       # each heater adds 10 °C to its own sensor
    got = coverage(model, ur, None, np.stack([np.full(n, 20.0), np.full(n, 30.0)]))
    np.testing.assert_allclose(got["steady_max"], np.full(n, 30.0), atol=1e-12)
    assert got["covered"]
    far = coverage(model, ur, None, np.stack([np.full(n, 20.0), np.full(n, 40.0)]))
    assert not far["covered"] and len(far["warnings"]) == n


def _record(model, T=600, seed=0):
    rng = np.random.default_rng(seed)
    nu = model.B.shape[1]
    u = np.repeat(rng.uniform(0, 1, (T // 30, nu)), 30, axis=0)
    A, B, C = (np.asarray(m) for m in (model.A, model.B, model.C))
    x = np.zeros(A.shape[0])
    y = []
    for k in range(T):
        y.append(C @ x + 20.0)
        x = A @ x + B @ u[k]
    return from_arrays(u, np.array(y) + 0.01 * rng.standard_normal((T, C.shape[0])), ts=1.0)


@pytest.mark.parametrize("cross,flagged", [(-0.02, False), (-0.2, True)])
def test_a_heater_lowering_a_sensor_is_judged_against_the_strongest_effect(cross, flagged):
    """Own gains of 10 °C per unit: a cross gain of -0.2 °C (2 %, a far zone's estimate
    scattering around zero) is no finding; one of -2 °C (20 %) is."""
    B = np.array([[1.0, cross], [0.0, 1.0]])
    model = StateSpace(0.9 * np.eye(2), B, np.eye(2), ts=1.0, u0=np.zeros(2),
                       y0=np.full(2, 20.0))
    found = heat_check(model, _record(model))
    lowers = [w for w in found["warnings"] if "lowers a sensor" in w]
    assert bool(lowers) == flagged
