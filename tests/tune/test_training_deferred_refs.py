"""`tune(reference_terms=...)`: the references simulated elsewhere while Adam's step compiles on
placeholders gives the same result as simulating them first, with the step compiled once; and
the host-side stand-ins for eager programs (stacking, the float32 cast, the guard's objective)
give the same bits as the eager `jnp` they replace."""

import logging

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.control import design
from jthermo.errors import ControlError
from jthermo.tune import group_batch, optimiser, robust_objective, tune
from jthermo.tune.training import best_reference_terms, caster, robust_objective_jit
from tests.control.loop import bed_plant
from tests.tune.test_optimiser import _scenarios


@pytest.fixture(scope="module")
def setup():
    plant = bed_plant(2, seed=1)
    batch = [[(plant, "custom", _scenarios(plant, seed=s)) for s in (0, 1)]]
    return plant, batch, design("pi_lambda", plant), [design("lqg", plant)]


def _same(a, b) -> bool:
    la, ta = jax.tree.flatten(a)
    lb, tb = jax.tree.flatten(b)
    return ta == tb and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


@pytest.mark.parametrize("dtype", [None, "float32"])
def test_deferred_references_give_the_same_tuning_with_one_step_program(setup, dtype, monkeypatch,
                                                                    caplog):
    plant, batch, start, refs = setup
    kw = {"scenarios": batch, "references": refs, "steps": 4, "train_dtype": dtype}
    direct = tune(start, plant, **kw)
    calls: list[int] = []
    best = best_reference_terms([start, *refs], batch, None)
    inner = optimiser.adam_iterates

    def spy(objective, z, batches, steps, lr, template=None):
        assert template is not None             # compiled on placeholders first
        return inner(objective, z, lambda: calls.append(1) or batches(), steps, lr, template)

    monkeypatch.setattr(optimiser, "adam_iterates", spy)
    caplog.clear()
    with jax.log_compiles(True), caplog.at_level(logging.WARNING):
        deferred = tune(start, plant, reference_terms=lambda: best, **kw)
    steps = [r for r in caplog.records
             if "Finished XLA compilation" in r.getMessage() and "make_step" in r.getMessage()]
    assert len(steps) == 1          # the placeholders have the references' shapes and dtypes
    assert calls == [1]
    assert _same(direct.controller, deferred.controller)
    np.testing.assert_array_equal(direct.history, deferred.history)
    assert direct.guard["chosen"] == deferred.guard["chosen"]
    with pytest.raises(ControlError, match="no finite cost"):
        tune(start, plant, reference_terms=lambda: [np.full_like(best[0], np.nan)], **kw)


def test_host_stacking_and_cast_are_the_eager_bits(setup):
    plant, batch, _, _ = setup
    groups = group_batch(batch[0])
    old = lambda *xs: jnp.stack(xs) if eqx.is_array(xs[0]) else xs[0]
    want = jax.tree.map(old, *[it[2] for it in batch[0]])
    got = jax.tree.leaves(groups[0].scenarios)
    assert len(got) == len(jax.tree.leaves(want))
    for a, b in zip(got, jax.tree.leaves(want)):
        assert a.dtype == b.dtype and a.weak_type == b.weak_type
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    low = caster("float32")
    for a, b in zip(jax.tree.leaves(low(groups)), jax.tree.leaves(groups)):
        if eqx.is_inexact_array(b):
            assert a.dtype == jnp.float32
            assert np.asarray(a).tobytes() == np.asarray(b.astype(jnp.float32)).tobytes()


def test_guard_objective_program_is_the_eager_value_bit_for_bit():
    rng = np.random.default_rng(3)
    for _ in range(50):
        v, best = rng.uniform(0.2, 3.0, (2, 9, 2))
        eager = float(robust_objective(jnp.asarray(v), jnp.asarray(best), 0.02))
        assert float(robust_objective_jit()(v, best, 0.02)) == eager
