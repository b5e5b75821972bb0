"""`closedloop.prepare_run`: the run program compiled before the real controller exists (the
simulate command does it in a thread while the printer's design model is computed), for a
controller designed on `cli.printer_model.shape_model` (the design model's shapes only)."""

from __future__ import annotations

import collections

import jax
import pytest
from jax import monitoring

from jthermo import closedloop as cl
from jthermo.cli.printer_model import PREPARE_SKIP, shape_model, stored_printer_model
from jthermo.control.design import FAMILIES, design
from jthermo.printer import make_printer
from jthermo.stored import split_arguments

LOWERING = "/jax/core/compile/jaxpr_to_mlir_module_duration"


def _structure(controller):
    """What keys the run program besides the values: tree, static leaves, shapes, dtypes."""
    treedef, static, _, arrays = split_arguments((controller,))
    return str(treedef), repr(static), [(a.shape, str(a.dtype)) for a in arrays]


@pytest.fixture(scope="module")
def printer_and_model():
    p = make_printer(3, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
    return p, stored_printer_model(p)


def _lowerings(fn) -> int:
    """How many programs JAX lowered while `fn()` ran (this process)."""
    events = collections.Counter()

    def count(name, _secs, **_):
        events[name] += 1

    monitoring.register_event_duration_secs_listener(count)
    try:
        fn()
    finally:
        monitoring.unregister_event_duration_listener(count)
    return events[LOWERING]


def test_the_prepared_program_is_the_one_run_calls(printer_and_model):
    p, model = printer_and_model
    kw = {"rollouts": 3, "duration": 47.0}     # shapes no other test uses: new to this process
    assert cl.prepare_run("tracking", design("pi_lambda", shape_model(p)), p, **kw)
    real = design("pi_lambda", model)
    out = {}
    assert _lowerings(lambda: out.update(cl.run("tracking", real, p, seed=5, **kw))) == 0
    # the figures are the real controller's, not the stand-in's
    assert out["metrics"] == cl.run("tracking", real, p, seed=5, **kw)["metrics"]
    # and the count can fail: unprepared shapes lower their program
    assert _lowerings(lambda: cl.run("tracking", real, p, seed=5, rollouts=3, duration=53.0)) > 0


@pytest.mark.parametrize("family", [f for f in FAMILIES if f not in PREPARE_SKIP])
def test_a_controller_designed_on_theshape_model_has_the_real_structure(printer_and_model, family):
    p, model = printer_and_model
    assert _structure(design(family, shape_model(p))) == _structure(design(family, model))


@pytest.mark.parametrize("family", PREPARE_SKIP)
def test_the_skipped_families_do_depend_on_the_model_values(printer_and_model, family):
    """Remove a family from `PREPARE_SKIP` once this fails: its structure no longer depends
    on the design model's values."""
    p, model = printer_and_model
    assert _structure(design(family, shape_model(p))) != _structure(design(family, model))


def test_prepare_run_declines_a_fitted_plant():
    from jthermo.models import StateSpace

    plant = StateSpace(jax.numpy.eye(1) * 0.9, jax.numpy.eye(1) * 0.1, jax.numpy.eye(1))
    assert cl.prepare_run("tracking", "untuned", plant) is False
