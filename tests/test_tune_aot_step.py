"""`minimise(batches=callable, template=...)`: Adam's step compiled ahead of time on a template
batch while the batches are still being made gives the same iterates as the plain call; a
template of other shapes falls back to compiling on the real batches; errors stay."""

import threading

import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.errors import ControlError
from jthermo.tune import minimise
from tests.test_tune_lbfgs import START, _quadratic

BATCHES = [jnp.array([2.0, 1.5]), jnp.array([1.0, 3.0])]


def test_template_step_gives_the_plain_iterates():
    plain = minimise(_quadratic, START, BATCHES, steps=12, lr=0.1, snapshots=3)
    made = threading.Event()

    def later():                 # the batches are made only after the step compiled
        made.set()
        return BATCHES

    aot = minimise(_quadratic, START, later, steps=12, lr=0.1, snapshots=3,
                   template=jnp.zeros_like(BATCHES[0]))
    assert made.is_set()
    np.testing.assert_array_equal(aot.history, plain.history)
    assert aot.tuned_cost == plain.tuned_cost and len(aot.snapshots) == len(plain.snapshots)
    np.testing.assert_array_equal(aot.controller.gain, plain.controller.gain)


def test_template_of_other_shapes_falls_back():
    plain = minimise(_quadratic, START, BATCHES[:1], steps=5, lr=0.1)
    other = minimise(_quadratic, START, lambda: BATCHES[:1], steps=5, lr=0.1,
                     template=jnp.ones((1, 2)))     # other shape: the step compiles again
    np.testing.assert_array_equal(other.history, plain.history)


def test_callable_batches_errors():
    with pytest.raises(ControlError, match="no training batch"):
        minimise(_quadratic, START, list, steps=2, template=jnp.zeros_like(BATCHES[0]))
    with pytest.raises(ControlError, match="no training batch"):
        minimise(_quadratic, START, list, steps=2, method="lbfgs")
    lb = minimise(_quadratic, START, lambda: BATCHES[:1], steps=20, method="lbfgs")
    assert lb.tuned_cost < 1e-6
