"""An unmeasured surroundings drift is one signal, fitted over all zones at once."""

import jax
import jax.numpy as jnp
import numpy as np
from scipy.stats import chi2

from jthermo.diagnose import decide as D
from jthermo.diagnose import mechanisms as M
from jthermo.diagnose.commondrift import common_drift_fit

jax.config.update("jax_enable_x64", True)

T, TS, LEVEL, NOISE = 1200, 1.0, 22.0, 0.02


def _record():
    """Two isolated zones, a fast one and a slow one (loss 1/100 and 1/1000 per s), that see one
    drift of the surroundings (knots every 300 s); the start is the truth, except the slow zone's
    own drift, which has the opposite sign (a per-zone fit's drift that traded with its gains)."""
    n = 2
    lay = M.make_layout(n, n, M.n_drift_knots(T, TS))
    rng = np.random.default_rng(5)
    u = np.repeat(rng.integers(0, 2, size=(T // 30 + 1, n)), 30, axis=0)[:T].astype(float)
    drift = 2.0 * np.sin(np.linspace(0.0, 2.5, lay.n_drift))
    Th = np.stack([M.initial_theta(lay, log_a=np.log(a), log_b=np.log(b), x0=40.0)
                   for a, b in ((0.01, [0.3, 0.02]), (0.001, [0.01, 0.04]))])
    f = {"u": jnp.asarray(u), "wdev": jnp.zeros(T), "Phi": jnp.asarray(M.drift_basis(T, TS, lay.n_drift)),
         "ts": jnp.asarray(TS), "t_ref": jnp.asarray(40.0), "ts_level": jnp.asarray(LEVEL),
         "ts_free": jnp.asarray(1.0), "u_pad": jnp.asarray(u.mean(axis=0))}
    rec = np.zeros(2 * n + lay.n_drift + 1)
    rec[:n] = 40.0
    rec[2 * n:2 * n + lay.n_drift] = drift
    on = jnp.asarray(M.on_vector(("ambient_variation",)))
    y = np.asarray(M.simulate_full(jnp.asarray(Th), on, {**f, "events": jnp.zeros((T, n)), "delay": 0.0},
                                   lay, jnp.asarray(rec)))
    y = y + NOISE * rng.normal(size=y.shape)
    start = Th.copy()
    start[:, lay.sl("drift")] = np.stack([drift - drift.mean(), -(drift - drift.mean())])
    start[:, lay.sl("ts0")] = drift.mean()
    return lay, f, y, start, drift, on


def test_common_drift_fit_shares_one_drift_and_keeps_the_zone_form():
    """The common fit takes both zones to one drift (the slow zone's wrong own drift is not kept)
    and predicts both to the noise; its θ, read by the per-zone simulation (drift mean-free per
    zone, its mean in the level offset), gives the same residual."""
    lay, f, y, start, drift, on = _record()
    th, res = common_drift_fit(start, y, f, LEVEL, 1.0, lay, 25)
    assert np.sqrt(np.mean(res ** 2)) < 1.5 * NOISE
    got = th[:, lay.sl("drift")]
    np.testing.assert_allclose(got[0], got[1])
    assert np.corrcoef(got[0], drift)[0, 1] > 0.95
    z = {**f, "ynb": jnp.zeros((T, 1)), "ybar": jnp.asarray(y.mean(axis=1)), "events": jnp.zeros(T),
         "delay": jnp.asarray(0.0)}
    for i in range(2):
        yi = np.asarray(M.simulate_zone(jnp.asarray(th[i]), on, z, lay))
        np.testing.assert_allclose(y[:, i] - yi, res[:, i], atol=1e-6)
    # the start (the slow zone's own drift) misses that zone by far more than the noise
    y1 = np.asarray(M.simulate_zone(jnp.asarray(start[1]), on, z, lay))
    assert np.sqrt(np.mean((y[:, 1] - y1) ** 2)) > 10 * NOISE


def test_an_unfinished_common_fit_goes_on_while_it_falls():
    """From a start far off (no drift, every zone's loss e times too fast, gains a third), a
    3-iteration fit is still falling (far above the noise); with continuation rounds it reaches
    the noise, and from there a further call changes nothing."""
    lay, f, y, start, drift, on = _record()
    far = start.copy()
    far[:, lay.sl("drift")] = 0.0
    far[:, lay.sl("log_b")] -= np.log(3.0)
    far[:, lay.sl("log_a")] += 1.0
    noise = y.size * NOISE ** 2
    _, short = common_drift_fit(far, y, f, LEVEL, 1.0, lay, 3)
    th, longer = common_drift_fit(far, y, f, LEVEL, 1.0, lay, 3, rounds=3)
    assert np.sum(short ** 2) > 100 * noise
    assert np.sum(longer ** 2) < 1.5 * noise
    _, again = common_drift_fit(th, y, f, LEVEL, 1.0, lay, 3)
    assert np.sum(again ** 2) <= np.sum(longer ** 2) * (1 + 1e-6)


def test_a_zone_contradicts_the_common_drift_only_beyond_chance():
    """Own-against-common likelihood ratios: below the Bonferroni χ² quantile at the diagnosis's
    level (shape parameters = knots - 1) nothing contradicts; one zone above it, or a diverged
    fit, does."""
    crit = chi2.isf(D.ALPHA / 3, 7)
    assert not D.drift_contradicted([3.6, -29.6, -3.3], 8)
    assert not D.drift_contradicted([0.99 * crit] * 3, 8)
    assert D.drift_contradicted([1.01 * crit, 0.0, 0.0], 8)
    assert D.drift_contradicted([1.0, float("nan")], 8)
    assert D.drift_contradicted([], 8)


def test_a_shared_drift_is_charged_its_knots_once():
    """The tests' degrees of freedom: a drift every zone shares (unmeasured surroundings, refitted
    by `common_drift_fit`, and the joint fits' record drift) adds its knots once, not per zone;
    per-zone drifts (measured constant surroundings) and every other mechanism add per zone."""
    n, knots = 4, M.n_drift_knots(3600, 1.0)
    lay = M.make_layout(n, n, knots)
    assert knots == 13
    assert M.n_added("ambient_variation", lay, shared_drift=True) == knots
    assert M.n_added("ambient_variation", lay, shared_drift=False) == n * knots
    for mech in ("heater_lag", "input_delay", "radiative_loss", "heat_accumulation"):
        assert M.n_added(mech, lay, shared_drift=True) == n * M.n_added_per_zone(mech, lay)
    assert M.n_added("heat_accumulation", lay, shared_drift=True) == 4 * n
