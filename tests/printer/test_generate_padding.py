"""`generate` simulates on a padded length and cuts back: the record equals the unpadded run.

The independent computation is the simulation program run on the record's own length, with
the PRBS drawn for that length (`inputs.prbs`); `generate` draws and simulates `bucket(T)`
samples instead and keeps the first `T`.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.identify.padding import bucket
from jthermo.inputs import prbs
from jthermo.printer import make_printer
from jthermo.printer.runs import _generate_fn, experiment_input, generate

EFFECTS = {"laser_exposure": {}, "recoat_cooling": {}, "ambient_variation": {"measured": True},
           "sensor_noise": {}}


def _unpadded(printer, experiment, T, seed, levels=(0.3, 0.7), noise_std=0.05):
    if experiment == "prbs":
        u = np.asarray(prbs(seed, T, printer.n_inputs, levels=levels, hold=(3, 15)))
    else:
        u = experiment_input(experiment, seed, T, printer.n_inputs, levels)
    y, d = jax.jit(_generate_fn, static_argnums=(5,))(
        printer, jnp.asarray(u), jax.random.key(seed), 0.5 * sum(levels), noise_std, True)
    return u, np.asarray(y), d


@pytest.mark.parametrize("zones, T, effects", [(1, 601, ()), (4, 437, EFFECTS),
                                               (16, 300, ("sensor_noise", "recoat_cooling"))])
def test_generate_equals_the_unpadded_run(zones, T, effects):
    assert bucket(T) > T                       # the record is padded
    pr = make_printer(zones, effects=effects, seed=3)
    data = generate(pr, duration=float(T) * pr.ts, seed=5)
    u, y, d = _unpadded(pr, "prbs", T, 5)
    assert data.n_samples == T
    np.testing.assert_array_equal(data.u, u)
    np.testing.assert_allclose(data.y, y, rtol=0, atol=1e-9)
    if pr.has("ambient_variation"):
        np.testing.assert_allclose(data.w[:, 0], np.asarray(d.ambient), atol=1e-9)
    if pr.has("recoat_cooling"):
        np.testing.assert_array_equal(data.w[:, -1], np.asarray(d.recoat))


def test_step_experiment_keeps_its_switch():
    pr = make_printer(2, seed=1)
    T = 333
    data = generate(pr, "step", duration=float(T) * pr.ts, seed=2)
    u, y, _ = _unpadded(pr, "step", T, 2)
    np.testing.assert_array_equal(data.u, u)
    assert data.u[T // 4 - 1, 0] == 0.3 and data.u[T // 4, 0] == 0.7
    np.testing.assert_allclose(data.y, y, rtol=0, atol=1e-9)


def test_lengths_of_one_bucket_share_a_prefix():
    pr = make_printer(3, effects=["sensor_noise"], seed=0)
    a = generate(pr, duration=1100.0, seed=7)
    b = generate(pr, duration=1200.0, seed=7)
    assert bucket(1100) == bucket(1200)
    np.testing.assert_array_equal(a.u, b.u[:1100])
    np.testing.assert_allclose(a.y, b.y[:1100], rtol=0, atol=1e-9)


def test_a_new_length_of_a_met_bucket_compiles_nothing():
    from jthermo import runtime

    runtime.count_compiles()
    pr = make_printer(2, effects=["laser_exposure"], seed=0)
    generate(pr, duration=1300.0, seed=1)
    before = runtime.compiled_programs()
    for T in (1290.0, 1310.0, 1450.0):
        assert bucket(int(T)) == bucket(1300)
        generate(pr, duration=T, seed=2)
    assert runtime.compiled_programs() == before
