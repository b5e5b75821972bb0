"""A tuning study (printers of two powders × the three scenario kinds) stacks into one vmapped
simulation, and that simulation gives each item what it gives alone."""

import jax
import numpy as np

from jthermo.closedloop import REALISTIC_EFFECTS, make_scenario
from jthermo.control import design
from jthermo.printer import make_printer
from jthermo.tune import SCENARIOS, batch_terms, group_batch, printer_model


def _study():
    plants = [make_printer(2, REALISTIC_EFFECTS, powder=p, seed=0) for p in ("PA12", "PA11")]
    return [(p, k, make_scenario(k, p, 40.0, jax.random.key(7 + i), n_rollouts=2))
            for p in plants for i, k in enumerate(SCENARIOS)]


def test_a_study_of_two_powders_and_three_kinds_is_one_group_equal_to_its_items():
    batch = _study()
    groups = group_batch(batch)
    assert len(groups) == 1 and groups[0].stacked
    # each powder's scenarios keep its own window centre (the builder is shared: the window is
    # an array leaf, not a compile-time constant)
    centres = [float(np.mean(sc.r)) for _, k, sc in batch if k == "powder"]
    np.testing.assert_allclose(centres, [174.0, 188.0])
    ctrl = design("pi_lambda", printer_model(batch[0][0]))
    together = np.asarray(batch_terms(ctrl, groups, None))
    alone = np.concatenate([np.asarray(batch_terms(ctrl, [it], None)) for it in batch])
    assert together.shape == (6, 2) and np.all(np.isfinite(together))
    np.testing.assert_allclose(together, alone, rtol=1e-10)
    # the powders differ: the same controller does not score the same on both
    assert not np.allclose(together[:3], together[3:], rtol=1e-3)


def test_lqg_gains_outside_jit_are_numpy_and_compile_nothing():
    """The LQG's Riccati gains at design (the finiteness check) and for its peak sensitivity
    run the same doubling iterations in NumPy (`compiled_gains`): nothing compiles, and they
    equal the traced gains of the closed loop."""
    import equinox as eqx
    from jax import monitoring

    from jthermo.control.lqg import compiled_gains
    from jthermo.control.margins import peak_sensitivity
    from tests.control.loop import bed_plant

    plant = bed_plant(7, seed=3)             # a state size no other test designs for
    ctrl = design("lqg", plant)
    events = []
    monitoring.register_event_duration_secs_listener(
        lambda ev, dur, **_: events.append(ev) if "backend_compile" in ev else None)
    g = compiled_gains(ctrl)
    ms = peak_sensitivity(plant, ctrl)
    assert not events
    assert ms["stable"] and 1.0 <= ms["ms"] < 3.0
    traced = eqx.filter_jit(lambda c: c.gains())(ctrl)
    for name in ("Lx", "Li", "L0", "M"):
        a, b = getattr(g, name), np.asarray(getattr(traced, name))
        assert isinstance(a, np.ndarray)
        np.testing.assert_allclose(a, b, rtol=1e-8, atol=1e-12 * np.max(np.abs(b)))


def test_shared_scenario_builder_gives_each_kind_its_own_values():
    """`make_scenario(..., shared=True)` builds tracking, powder and print with one program
    and the same values as each kind's own builder."""
    plant = make_printer(2, REALISTIC_EFFECTS, seed=0)
    for k in SCENARIOS:
        own = make_scenario(k, plant, 120.0, jax.random.key(3), n_rollouts=2)
        shared = make_scenario(k, plant, 120.0, jax.random.key(3), n_rollouts=2, shared=True)
        assert shared.kind == own.kind
        for a, b in zip(jax.tree.leaves(own), jax.tree.leaves(shared)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert float(np.sum(np.asarray(shared.d.laser))) > 0       # print: the laser is on


def test_held_out_terms_simulates_equal_controllers_once(monkeypatch):
    """The start design and the same classical design made again are one simulation."""
    import jthermo.tune.report as report

    plant = make_printer(2, REALISTIC_EFFECTS, seed=0)
    model = printer_model(plant)
    a, b, c = design("pi_lambda", model), design("pi_lambda", model), design("pi_untuned", model)
    calls = []

    def fake_terms(ctrl, batch, weights):
        calls.append(ctrl)
        n = sum(len(g.index) for g in batch)
        return np.full((n, 2), 2.0 if ctrl is c else 1.0)

    monkeypatch.setattr(report, "batch_terms", fake_terms)
    r = report.held_out_terms({"start": a, "lambda": b, "untuned": c}, {"p": plant}, (7,),
                              rollouts=1, duration=20.0)
    assert len(calls) == 2 and calls[0] is a and calls[1] is c
    assert r["start"] == r["lambda"] and r["untuned"]["p"]["cost"] == 2.0
    # in chunks of 2 items (the 3 of one plant: two batches, the last filled up): same result
    calls.clear()
    again = report.held_out_terms({"start": a, "lambda": b, "untuned": c}, {"p": plant}, (7,),
                                  rollouts=1, duration=20.0, chunk=2)
    assert len(calls) == 4 and again == r
