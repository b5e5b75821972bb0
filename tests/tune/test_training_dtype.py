"""`tune(..., train_dtype="float32")`: the training objective in single precision has the
gradient of the double-precision one (checked against central differences of the latter) to
single-precision accuracy, the parameters stay float64, and the guard judges in float64."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from jthermo.control import design
from jthermo.errors import ControlError
from jthermo.tune import batch_terms, group_batch, robust_objective, tune
from jthermo.tune.training import caster
from tests.control.loop import bed_plant
from tests.helpers import central_difference
from tests.tune.test_optimiser import _scenarios


def test_float32_objective_gradient_matches_float64_central_differences():
    plant = bed_plant(2, seed=1)
    groups = group_batch([(plant, "custom", _scenarios(plant, seed=s)) for s in (0, 1)])
    start = design("pi_lambda", plant)
    ref = batch_terms(start, groups, None)
    low = caster("float32")
    g32, ref32 = low(groups), low(ref)
    params, static = eqx.partition(start, eqx.is_inexact_array)
    flat, unravel = ravel_pytree(params)

    def objective(th, batch, r, cast):
        c = eqx.combine(unravel(th), static)
        return robust_objective(batch_terms(cast(c), batch, None), r)

    f64 = jax.jit(lambda th: objective(th, groups, ref, lambda c: c))
    f32 = jax.jit(lambda th: objective(th, g32, ref32, low))
    th = jnp.asarray(flat) * 1.05              # away from the start, where the value is 0
    assert f32(th).dtype == jnp.float32
    g = np.asarray(jax.grad(f32)(th))
    assert g.dtype == np.float64                # the gradient comes back in the parameters'
    free = np.flatnonzero(np.abs(g) > 0)
    assert free.size >= 4
    fd = central_difference(lambda x: f64(th.at[free].set(x)), np.asarray(th)[free])
    np.testing.assert_allclose(g[free], fd, rtol=2e-3, atol=1e-6 * np.max(np.abs(fd)))
    np.testing.assert_allclose(float(f32(th)), float(f64(th)), rtol=1e-4, atol=1e-6)


def test_tune_in_float32_returns_a_float64_controller_judged_in_float64():
    plant = bed_plant(2, seed=1)
    batch = [[(plant, "custom", _scenarios(plant, seed=0))]]
    start = design("pi_lambda", plant)
    res = tune(start, plant, scenarios=batch, steps=3, train_dtype="float32")
    for leaf in jax.tree.leaves(eqx.filter(res.controller, eqx.is_inexact_array)):
        assert leaf.dtype == jnp.float64
    assert res.guard is not None and np.isfinite(res.tuned_cost)
    # the guard's reference figures are the double-precision terms of the start
    want = np.asarray(batch_terms(start, group_batch(batch[0]), None))[:, 1]
    np.testing.assert_array_equal(np.asarray(res.guard["reference_mse"]), want)
    with pytest.raises(ControlError, match="train_dtype"):
        tune(start, plant, scenarios=batch, steps=1, train_dtype="float16")
