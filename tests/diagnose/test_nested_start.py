"""A candidate nests the baseline: its per-zone fit never ends above the baseline's cost, even
where LM from the mechanism's neutral start misses the nested optimum (`select._keep_nested`,
`mechanisms.near_off`)."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.diagnose import baseline as B
from jthermo.diagnose import mechanisms as M
from jthermo.diagnose import select as S
from jthermo.diagnose.fitting import fit_zones, sim_zones

jax.config.update("jax_enable_x64", True)

T, N, TS, LEVEL = 600, 2, 1.0, 25.0


def _record(seed=0):
    """Two first-order zones (the baseline's class: no mechanism) on PRBS inputs, 0.03 °C noise."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.integers(0, 2, size=(T // 15 + 1, N)), 15, axis=0)[:T] * 0.8
    a, b = np.array([0.004, 0.006]), np.array([[0.3, 0.04], [0.05, 0.25]])
    x = np.array([40.0, 35.0])
    y = np.empty((T, N))
    for k in range(T):
        y[k] = x
        x = x + TS * (-a * (x - LEVEL) + b @ u[k])
    return y + 0.03 * rng.standard_normal((T, N)), u


def _problem(y, u, lay, n_iter):
    shared = {"u": jnp.asarray(u), "ts_level": jnp.asarray(LEVEL), "ts_free": jnp.asarray(0.0),
              "wdev": jnp.zeros(T), "Phi": jnp.asarray(M.drift_basis(T, TS, lay.n_drift)),
              "u_pad": jnp.asarray(u[0]), "ts": jnp.asarray(TS), "t_ref": jnp.asarray(float(y.mean()))}
    base = lay.mask(["log_a", "log_b", "x0"])

    def fit(sets, starts):
        """select.diagnose's `fit_sets` on this record: per-zone fits of each set, (θ, residuals)."""
        K = len(sets)
        masks = np.concatenate([np.tile(np.minimum(base + sum(lay.mask(M.MECH_PARAMS[m]) for m in st), 1),
                                         (N, 1)) for st in sets])
        on = jnp.asarray(np.concatenate([np.tile(M.on_vector(st), (N, 1)) for st in sets]))
        per = {"y": jnp.asarray(np.tile(y.T, (K, 1))),
               "ynb": jnp.asarray(np.tile(y[:, ::-1].T[:, :, None], (K, 1, 1))),
               "ybar": jnp.asarray(np.tile(y.mean(axis=1), (K * N, 1))),
               "events": jnp.zeros((K * N, T)), "delay": jnp.zeros(K * N)}
        th, _, _ = fit_zones(jnp.asarray(starts.reshape(K * N, -1)), jnp.asarray(masks), on, per, shared,
                             lay, n_iter, 12)
        ys = np.asarray(sim_zones(th, on, per, shared, lay)).reshape(K, N, T).transpose(0, 2, 1)
        return np.asarray(th).reshape(K, N, -1), y[None] - ys

    return fit


def test_candidate_never_ends_above_the_nested_baseline():
    y, u = _record()
    lay = M.make_layout(N, N, M.n_drift_knots(T, TS))
    th0 = np.stack([M.initial_theta(lay, log_a=np.log(0.01), log_b=np.log([0.1, 0.1]), x0=y[0, i])
                    for i in range(N)])
    thb = B.fit(th0, y, u, TS, LEVEL, 0.0, lay)
    res_b = y - B.simulate(thb, u, u[0], TS, LEVEL, 0.0, lay)
    sse_b = np.sum(res_b ** 2, axis=0)
    mechs = ["radiative_loss", "heat_accumulation", "heater_lag", "lateral_conduction"]
    neutral = np.stack([M.initial_theta(lay, log_a=thb[i, lay.sl("log_a")][0], log_b=thb[i, lay.sl("log_b")],
                                        x0=thb[i, lay.sl("x0")][0]) for i in range(N)])
    fit = _problem(y, u, lay, S.N_ITER)
    th, res = fit([(m,) for m in mechs], np.stack([neutral] * len(mechs)))
    # constructed: data of the baseline's class; from the neutral starts (half the loss
    # radiative, a wall at γ = 1, a 5 s lamp, a coupling of 5 % of the loss) the diagnosis's LM
    # (N_ITER iterations) ends above the baseline it nests in every zone
    worse = np.sum(res ** 2, axis=1) > sse_b[None]
    assert worse.sum() >= 4, worse
    th2, res2, redone = S._keep_nested(fit, mechs, th, res, neutral, res_b, lay)
    # refitted: the worse zones, but a lamp that already ended at its floor (the nearly-off start)
    at_floor = np.array([m == "heater_lag" for m in mechs])[:, None] & (
        M.lamp_tau(th[:, :, lay.sl("log_tauh")][..., 0]) < 2 * M.TAUH_MIN)
    np.testing.assert_array_equal(redone, worse & ~at_floor)
    sse2 = np.sum(res2 ** 2, axis=1)
    # the nested optimum is reached to within the nearly-off start's own distance from it; the
    # lamp's time constant has a floor (TAUH_MIN = 0.05 s), so heater_lag nests the baseline only
    # in its limit: within 5 % here (0.05 s of lag on this PRBS), not to 1e-6
    exact = np.array([m != "heater_lag" for m in mechs])
    assert np.all(sse2[exact] <= sse_b[None] * (1 + 1e-6)), sse2 / sse_b[None]
    assert np.all(sse2[~exact] <= sse_b[None] * 1.05), sse2 / sse_b[None]
    # the zones that were not worse keep their fits, the others the better of the two
    np.testing.assert_array_equal(th2[~worse], th[~worse])
    assert np.all(sse2 <= np.sum(res ** 2, axis=1))


def test_near_off_is_the_nested_model():
    """`near_off`: within about OFF_FRACTION of the nested model's simulation; exactly-off
    mechanisms (delay, exponent, drift) are left at their neutral start."""
    y, u = _record(1)
    lay = M.make_layout(N, N, M.n_drift_knots(T, TS))
    th = np.stack([M.initial_theta(lay, log_a=np.log(0.004), log_b=np.log([0.3, 0.04]), x0=y[0, i])
                   for i in range(N)])
    shared = {"u": jnp.asarray(u), "ts_level": jnp.asarray(LEVEL), "ts_free": jnp.asarray(0.0),
              "wdev": jnp.zeros(T), "Phi": jnp.asarray(M.drift_basis(T, TS, lay.n_drift)),
              "u_pad": jnp.asarray(u[0]), "ts": jnp.asarray(TS), "t_ref": jnp.asarray(float(y.mean()))}
    per = {"y": jnp.asarray(y.T), "ynb": jnp.asarray(y[:, ::-1].T[:, :, None]),
           "ybar": jnp.asarray(np.tile(y.mean(axis=1), (N, 1))), "events": jnp.ones((N, T)),
           "delay": jnp.zeros(N)}
    y0 = np.asarray(sim_zones(jnp.asarray(th), jnp.zeros((N, 8)), per, shared, lay))
    for m in M.MECHANISMS:
        t = M.near_off(th, m, lay)
        if m not in M.RESTARTED:
            np.testing.assert_array_equal(t, th)
            continue
        on = jnp.asarray(np.tile(M.on_vector([m]), (N, 1)))
        ym = np.asarray(sim_zones(jnp.asarray(t), on, per, shared, lay))
        yn = np.asarray(sim_zones(jnp.asarray(th), on, per, shared, lay))
        off = np.max(np.abs(ym - y0))
        assert off < 0.05 * np.max(np.abs(yn - y0)), (m, off)
