"""`run` draws the printer's measurement noise inside the scan (`Printer.noise_stream`), one
sample at a time: the same normal draws as the whole-run draw (`Printer.sample_noise`, bit for
bit), so the run's figures equal those of the materialised scenario to round-off."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.closedloop import REALISTIC_EFFECTS, make_scenario
from jthermo.closedloop.engine import (
    RECOAT_FREE_KINDS,
    RUN_NOISE_STD,
    _run_metrics,
    _scenario_metrics,
    rollout_noise,
)
from jthermo.control.pi import DiagonalPI
from jthermo.errors import ModelError
from jthermo.printer import make_printer
from jthermo.printer.noise import in_scan_supported, normal_row


@pytest.mark.parametrize("shape,rows", [((7, 3), (0, 6)), ((5000, 16), (0, 1, 4096, 4999))])
def test_normal_row_is_jax_normal_bit_for_bit(shape, rows):
    key = jax.random.key(11)
    whole = np.asarray(jax.random.normal(key, shape, jnp.float64))
    one = jax.jit(normal_row, static_argnums=2)
    for t in rows:
        assert np.array_equal(np.asarray(one(key, t, shape[1])), whole[t])


@pytest.mark.parametrize("effects,areas", [(REALISTIC_EFFECTS, False), (REALISTIC_EFFECTS, True),
                                           (("lateral_conduction",), False)])
def test_stream_equals_sample_noise(effects, areas):
    pr = make_printer(4, effects, seed=0, areas=areas)
    key, T = jax.random.key(5), 50
    whole = np.asarray(pr.sample_noise(key, T, 0.05))
    stream = pr.noise_stream(key, 0.05)

    def body(c, k):
        v, c = stream.at(k, c)
        return c, v

    _, rows = jax.lax.scan(body, stream.init(), jnp.arange(T))
    # the same normal draws (bit for bit, above); scaling and the AR(1) filter may round
    # differently inside another fusion: equal to a few float64 ulps
    np.testing.assert_allclose(np.asarray(rows), whole, rtol=1e-14, atol=1e-16)


@pytest.mark.parametrize("kind", ["tracking", "print"])
def test_run_in_scan_equals_materialised(kind):
    assert in_scan_supported(jnp.float64)   # so `_scenario_metrics` really draws in the scan
    pr = make_printer(4, REALISTIC_EFFECTS, seed=0)
    ctrl = DiagonalPI.untuned(4, ts=pr.ts)
    key, B, dur = jax.random.key(2), 3, 200.0
    lean = _scenario_metrics(kind, pr, ctrl, dur, key, B)[0]
    sc = make_scenario(kind, pr, dur, key, n_rollouts=B, noise_std=RUN_NOISE_STD)
    dense = _run_metrics(pr, ctrl, sc, kind not in RECOAT_FREE_KINDS)[0]
    for name in dense:
        np.testing.assert_allclose(float(lean[name]), float(dense[name]), rtol=1e-12, atol=1e-15,
                                   err_msg=name)
    # the streams are those the scenario drew its noise from: the same first samples
    streams = eqx.filter_jit(rollout_noise)(pr, key, B)
    v0 = jax.vmap(lambda s: s.at(0, s.init())[0])(streams)
    np.testing.assert_allclose(np.asarray(v0), np.asarray(sc.v[:, 0]), rtol=1e-14, atol=1e-16)


def test_float32_printer_refuses_stream():
    pr = make_printer(2, REALISTIC_EFFECTS, seed=0)
    pr32 = jax.tree.map(lambda a: a.astype(jnp.float32) if eqx.is_inexact_array(a) else a, pr)
    with pytest.raises(ModelError, match="needs float64"):
        pr32.noise_stream(jax.random.key(0))
