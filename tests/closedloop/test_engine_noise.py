"""`run` draws the printer's measurement noise inside the scan (`Printer.noise_stream`), one
sample at a time: the distribution of the whole-run draw (`Printer.sample_noise`), other
draws. Checked here: the statistics per channel (std, lag-1 autocorrelation, no correlation
between channels), determinism from the key, and that the run's figures equal those of the
scenario materialised with the same stream."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.closedloop import REALISTIC_EFFECTS, make_scenario
from jthermo.closedloop.engine import (
    RECOAT_FREE_KINDS,
    RUN_NOISE_STD,
    rollout_noise,
    run_metrics,
    run_scenario,
    scenario_metrics,
)
from jthermo.control.pi import DiagonalPI
from jthermo.printer import make_printer


def _lag1(x):
    x = x - x.mean(axis=0)
    return (x[1:] * x[:-1]).mean(axis=0) / (x * x).mean(axis=0)


def _expected(pr, white):
    """Per-channel std and lag-1 autocorrelation of `sample_noise(key, T, white)`."""
    ny, nz = pr.n_outputs, pr.zones
    var = np.full(ny, white ** 2)
    rho = np.zeros(ny)
    if pr.has("sensor_noise"):
        p = {k: float(v) for k, v in pr.effects["sensor_noise"].items()}
        var += p["white_std_C"] ** 2
        var[:nz] += p["coloured_std_C"] ** 2
        rho[:nz] = p["pole"] * p["coloured_std_C"] ** 2 / var[:nz]
    return np.sqrt(var), rho


@pytest.mark.parametrize("effects,areas", [(REALISTIC_EFFECTS, False), (REALISTIC_EFFECTS, True),
                                           (("lateral_conduction",), False)])
def test_stream_has_the_distribution_of_sample_noise(effects, areas):
    pr = make_printer(4, effects, seed=0, areas=areas)
    T, white = 40000, 0.05
    stream = np.asarray(eqx.filter_jit(lambda s: s.sample(T))(pr.noise_stream(jax.random.key(5), white)))
    whole = np.asarray(pr.sample_noise(jax.random.key(5), T, white))
    std, rho = _expected(pr, white)
    for v in (stream, whole):   # the same checks hold the old draw
        # sampling error of a std over 40000 samples of an AR(1) with pole 0.9: ~1.5 %
        np.testing.assert_allclose(v.std(axis=0), std, rtol=0.05)
        np.testing.assert_allclose(_lag1(v), rho, atol=0.03)
        # channels independent: the standard error of a correlation between two AR(1) channels
        # of pole 0.9 over 40000 samples is ~0.015
        corr = np.corrcoef(v.T) - np.eye(v.shape[1])
        assert np.abs(corr).max() < 0.06
        assert np.abs(v.mean(axis=0)).max() < 0.02
    # a measurably different stream would fail: the old and new draws are not the same numbers
    assert not np.allclose(stream[:10], whole[:10])


def test_stream_is_deterministic_per_key():
    pr = make_printer(3, REALISTIC_EFFECTS, seed=0)
    sample = eqx.filter_jit(lambda s: s.sample(64))
    a = np.asarray(sample(pr.noise_stream(jax.random.key(1), 0.05)))
    b = np.asarray(sample(pr.noise_stream(jax.random.key(1), 0.05)))
    c = np.asarray(sample(pr.noise_stream(jax.random.key(2), 0.05)))
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    assert len(np.unique(a[:, 0])) == 64   # no sample repeats another


@pytest.mark.parametrize("kind", ["tracking", "print"])
def test_run_in_scan_equals_materialised(kind):
    pr = make_printer(4, REALISTIC_EFFECTS, seed=0)
    ctrl = DiagonalPI.untuned(4, ts=pr.ts)
    key, B, dur = jax.random.key(2), 3, 200.0
    lean = scenario_metrics(kind, pr, ctrl, dur, key, B)[0]
    sc = run_scenario(kind, pr, dur, key, B)
    # the scenario of `run` is `make_scenario`'s with the streams' noise in place of its own
    plain = make_scenario(kind, pr, dur, key, n_rollouts=B, noise_std=RUN_NOISE_STD)
    streams = eqx.filter_jit(rollout_noise)(pr, key, B)
    np.testing.assert_array_equal(np.asarray(sc.r), np.asarray(plain.r))
    np.testing.assert_array_equal(np.asarray(sc.v[1]), np.asarray(
        eqx.filter_jit(lambda s: s.sample(sc.r.shape[1]))(jax.tree.map(lambda a: a[1], streams))))
    dense = run_metrics(pr, ctrl, sc, kind not in RECOAT_FREE_KINDS)[0]
    for name in dense:
        np.testing.assert_allclose(float(lean[name]), float(dense[name]), rtol=1e-12, atol=1e-15,
                                   err_msg=name)


def test_float32_printer_gets_float32_noise():
    pr = make_printer(2, REALISTIC_EFFECTS, seed=0)
    pr32 = jax.tree.map(lambda a: a.astype(jnp.float32) if eqx.is_inexact_array(a) else a, pr)
    v = eqx.filter_jit(lambda s: s.sample(5))(pr32.noise_stream(jax.random.key(0), 0.05))
    assert v.dtype == jnp.float32 and v.shape == (5, pr.n_outputs)
    assert np.all(np.isfinite(np.asarray(v)))
