"""`plant_ensemble` draws its perturbed copies in NumPy and checks their steady input with one
compiled program: the copies equal the same draws applied with jnp, bit for bit, and building
the ensemble compiles (almost) nothing."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jthermo.closedloop import REALISTIC_EFFECTS
from jthermo.printer import make_printer
from jthermo.tune import plant_ensemble


def _reference(printer, n, spread=0.15, shift_c=15.0, seed=0):
    """The copies as the formula reads, every product in jnp (the former eager path)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 4242]))
    out, n_z = [printer], printer.zones
    while len(out) < n + 1:
        f = 1.0 + spread * rng.uniform(-1, 1, 3)
        jit_ = lambda: 1.0 + spread / 3 * rng.uniform(-1, 1, n_z)
        p = eqx.tree_at(lambda q: (q.capacity, q.loss, q.gain, q.surroundings), printer,
                        (printer.capacity * f[0] * jit_(), printer.loss * f[1] * jit_(),
                         printer.gain * f[2] * jit_()[None, :],
                         printer.surroundings + shift_c * rng.uniform(-1, 1)))
        p = eqx.tree_at(lambda q: q.effects["radiative_loss"]["emissivity"], p,
                        p.effects["radiative_loss"]["emissivity"]
                        * (1.0 + 0.5 * spread * rng.uniform(-1, 1)))
        u = np.asarray(p.steady_input())[:n_z]
        if np.all((u > 0.1) & (u < 0.9)):
            out.append(p)
    return out


def test_ensemble_equals_the_jnp_formula_bit_for_bit_and_compiles_once():
    printer = make_printer(3, REALISTIC_EFFECTS, seed=0)
    counts = []

    def listener(event, duration, **kw):
        if "backend_compile" in event:
            counts.append(event)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        got = plant_ensemble(printer, 3, seed=5)
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    want = _reference(printer, 3, seed=5)
    assert len(got) == len(want) == 4
    for a, b in zip(got, want):
        la, lb = jax.tree.leaves(eqx.filter(a, eqx.is_array)), jax.tree.leaves(
            eqx.filter(b, eqx.is_array))
        assert len(la) == len(lb)
        for x, y in zip(la, lb):
            assert x.dtype == y.dtype and x.shape == y.shape
            assert np.array_equal(np.asarray(x), np.asarray(y))
    # the copies differ from the printer and keep its structure (one vmapped simulation)
    assert not np.allclose(np.asarray(got[1].capacity), np.asarray(printer.capacity))
    assert jax.tree.structure(got[1]) == jax.tree.structure(printer)
    assert isinstance(got[1].capacity, jnp.ndarray)
    assert len(counts) <= 2
