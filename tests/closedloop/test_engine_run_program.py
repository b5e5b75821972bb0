"""`run`'s program on the printer computes its figures with less work and the same values:
the measurement noise drawn `noise.CHUNK` samples at a time (each random vector once) equals
the one-draw-per-sample recipe, and the signals a printer scenario holds constant
(`engine.HELD_SIGNALS`: set points, the laser where a kind has none) read once instead of
scanned give the same figures as the scanned arrays."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.closedloop import REALISTIC_EFFECTS, make_scenario
from jthermo.closedloop.engine import (
    HELD_SIGNALS,
    RECOAT_FREE_KINDS,
    RUN_NOISE_STD,
    rollout_noise,
    run_metrics,
)
from jthermo.control.pi import DiagonalPI
from jthermo.printer import make_printer
from jthermo.printer.noise import CHUNK


def _per_sample(stream, n):
    """The stream's recipe with one draw per sample (what `NoiseStream.at` computed before
    it drew `CHUNK` samples at a time)."""
    out, c = [], jnp.zeros((stream.zones,), stream.dtype)
    for k in range(n):
        n_e = stream.ny + (0 if stream.sensor is None else stream.zones)
        e = jax.random.normal(jax.random.fold_in(stream.key, k), (n_e,), jnp.float32)
        v, c = stream.shape_noise(k, c, e.astype(stream.dtype))
        out.append(v)
    return np.stack(out)


@pytest.mark.parametrize("effects", [REALISTIC_EFFECTS, ("lateral_conduction",)])
def test_chunked_noise_equals_one_draw_per_sample(effects):
    pr = make_printer(3, effects, seed=0)
    stream = pr.noise_stream(jax.random.key(7), 0.05)
    n = 2 * CHUNK + 5        # across two refills and into a third chunk
    got = np.asarray(eqx.filter_jit(lambda s: s.sample(n))(stream))
    np.testing.assert_allclose(got, _per_sample(stream, n), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("kind", ["tracking", "print", "preheat"])
def test_held_signals_give_the_scanned_figures(kind):
    pr = make_printer(4, REALISTIC_EFFECTS, seed=0)
    ctrl = DiagonalPI.untuned(4, ts=pr.ts)
    key, B = jax.random.key(3), 3
    sc = make_scenario(kind, pr, 150.0, key, n_rollouts=B, noise_std=RUN_NOISE_STD)
    held = HELD_SIGNALS[kind]
    # what `held` claims: the set points (and the laser, where held) constant over the run
    assert np.all(np.asarray(sc.r) == np.asarray(sc.r)[:, :1])
    if "laser" in held:
        assert not np.any(np.asarray(sc.d.laser))
    noise = rollout_noise(pr, key, B)
    recoat = kind not in RECOAT_FREE_KINDS
    run = eqx.filter_jit(run_metrics)
    a = run(pr, ctrl, sc, recoat, noise, held)[0]
    b = run(pr, ctrl, sc, recoat, noise, ())[0]
    for k in a:
        np.testing.assert_allclose(float(a[k]), float(b[k]), rtol=1e-12, err_msg=k)
