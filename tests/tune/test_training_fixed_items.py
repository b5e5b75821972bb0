"""`fixed_items`: where a schedule feed-forward's taps act on nothing (the tracking scenario has
no events) `tune` holds the start's terms instead of simulating them every step; the tuning is
the same as with every item simulated (histories to rounding, the same guard's choice), at one
zone and at sixteen, with the references simulated first or handed in (`with_first`)."""

import jax
import numpy as np
import pytest

from jthermo.closedloop import REALISTIC_EFFECTS
from jthermo.control import design
from jthermo.printer import make_printer
from jthermo.tune import training
from jthermo.tune.ff_init import FF_FIELDS
from jthermo.tune.report import printer_model
from jthermo.tune.training import best_reference_terms, fixed_items, make_batches, tune

KINDS = ("tracking", "print")


def _case(zones):
    p = make_printer(zones, REALISTIC_EFFECTS, powder="PA12", seed=0)
    model = printer_model(p)
    start = design("pi_ff", model)
    # taps away from zero, so that a wrongly fixed item would show
    start = type(start)(feedback=start.feedback, h_recoat=start.h_recoat + 0.2,
                        h_laser=start.h_laser + 0.3)
    batch = make_batches([p], KINDS, rollouts=1, duration=60.0, seed=3)
    return p, model, start, batch


def test_only_the_scenario_without_events_is_fixed():
    _, _, start, batch = _case(1)
    assert fixed_items(start, FF_FIELDS, batch[0]).tolist() == [True, False]
    assert fixed_items(start, None, batch[0]) is None                 # feedback tuned too
    assert fixed_items(start.feedback, FF_FIELDS, batch[0]) is None   # no feed-forward


@pytest.mark.parametrize("zones", [1, 16])
@pytest.mark.parametrize("deferred", [False, True])
def test_fixed_items_give_the_tuning_of_every_item_simulated(zones, deferred, monkeypatch):
    p, model, start, batch = _case(zones)
    refs = [design("pi_lambda", model)]
    kw = {"scenarios": batch, "validation": batch[0], "references": refs, "steps": 3,
          "lr": 0.2, "params": FF_FIELDS, "ms_max": 2.0, "ms_model": model, "snapshots": 3}
    if deferred:
        got = best_reference_terms([start, *refs], batch, None, with_first=True)
        kw["reference_terms"] = lambda: got
    fast = tune(start, p, **kw)
    monkeypatch.setattr(training, "fixed_items", lambda *a: None)
    full = tune(start, p, **kw)
    np.testing.assert_allclose(fast.history, full.history, rtol=1e-9, atol=1e-12)
    assert fast.history[-1] < fast.history[0]          # the taps moved the cost
    assert fast.guard["chosen"] == full.guard["chosen"]
    assert fast.guard["ms_constraint"] == full.guard["ms_constraint"]
    for a, b in zip(jax.tree.leaves(fast.controller), jax.tree.leaves(full.controller)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-9, atol=1e-12)
