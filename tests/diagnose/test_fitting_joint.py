"""The diagnosis's joint fit: every zone's parameters at once by the coupled simulation error."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.diagnose import mechanisms as M
from jthermo.diagnose.fitting import fit_joint

jax.config.update("jax_enable_x64", True)

MECHS = ("heater_lag", "lateral_conduction", "radiative_loss")


def _prbs(T, n, seed):
    rng = np.random.default_rng(seed)
    return np.repeat(rng.integers(0, 2, size=(T // 20 + 1, n)), 20, axis=0)[:T].astype(float)


def _problem(T=300):
    """Two coupled zones at rest at 22 °C (heaters off before the record), lag + exchange +
    radiation: the true parameters, the record, and the simulation's inputs."""
    n = 2
    lay = M.make_layout(n, n, M.n_drift_knots(T, 1.0))
    u = _prbs(T, n, 4)
    Th = np.stack([M.initial_theta(lay, log_a=np.log(0.006 + 0.001 * i), log_b=np.log([0.5, 0.05][::1 - 2 * i]),
                                   x0=22.0) for i in range(n)])
    Th[:, lay.sl("log_tauh")] = np.log([15.0, 12.0])[:, None]
    Th[:, lay.sl("log_k")] = np.log(0.002)
    Th[:, lay.sl("rad_share")] = 0.5
    f = {"u": jnp.asarray(u), "wdev": jnp.zeros(T), "Phi": jnp.asarray(M.drift_basis(T, 1.0, lay.n_drift)),
         "ts": 1.0, "t_ref": 40.0}
    per = {"events": jnp.zeros((1, T, n)), "delay": jnp.zeros(1), "ts_level": jnp.full(1, 22.0),
           "ts_free": jnp.zeros(1), "u_pad": jnp.zeros((1, n))}
    rec = np.zeros(2 * n + lay.n_drift + 1)
    rec[:n] = 22.0
    rec[n:2 * n] = 22.0
    on = M.on_vector(MECHS)
    y = np.asarray(M.simulate_full(jnp.asarray(Th), jnp.asarray(on), {**f, **{k: v[0] for k, v in per.items()}},
                                   lay, jnp.asarray(rec)))
    free = np.zeros(n * lay.size + rec.size)
    free[:n * lay.size] = np.tile(lay.mask(("log_a", "log_b", "log_tauh", "log_k", "rad_share")), n)
    free[n * lay.size:n * lay.size + n] = 1.0
    return lay, Th, f, per, rec, on, y, free


def test_joint_fit_recovers_coupled_zones():
    lay, Th, f, per, rec, on, y, free = _problem()
    start = Th.copy()
    start[:, lay.sl("log_tauh")] = np.log(5.0)
    start[:, lay.sl("log_k")] = np.log(0.0005)
    start[:, lay.sl("log_a")] += 0.3
    start[:, lay.sl("rad_share")] = 0.0
    th, _, yh, c = fit_joint(jnp.asarray(start[None]), jnp.asarray(on[None]), jnp.asarray(rec[None]),
                             jnp.asarray(free[None]), jnp.asarray(y), jnp.ones(y.shape[0]), per, f, lay, 40, 24)
    assert float(c[0]) < 1e-6 * float(np.var(y))
    np.testing.assert_allclose(np.asarray(yh[0]), y, atol=2e-3)
    tau = M.lamp_tau(np.asarray(th[0][:, lay.sl("log_tauh")][:, 0]))
    np.testing.assert_allclose(tau, [15.0, 12.0], rtol=0.05)
    np.testing.assert_allclose(np.exp(np.asarray(th[0][:, lay.sl("log_k")][:, 0])), 0.002, rtol=0.1)


def test_joint_fit_padding_weight_ignores_padded_samples():
    """Samples with weight 0 do not move the fit: a record padded with garbage gives the fit of
    the unpadded record."""
    lay, Th, f, per, rec, on, y, free = _problem(T=200)
    T = y.shape[0]
    w = np.r_[np.ones(150), np.zeros(T - 150)]
    ybad = y.copy()
    ybad[150:] += 30.0
    start = Th.copy()
    start[:, lay.sl("log_a")] += 0.2
    args = (jnp.asarray(start[None]), jnp.asarray(on[None]), jnp.asarray(rec[None]), jnp.asarray(free[None]))
    th_w, *_ = fit_joint(*args, jnp.asarray(ybad), jnp.asarray(w), per, f, lay, 15, 24)
    th_c, *_ = fit_joint(*args, jnp.asarray(y), jnp.asarray(w), per, f, lay, 15, 24)
    np.testing.assert_allclose(np.asarray(th_w), np.asarray(th_c), atol=1e-9)


def test_joint_residual_jacobian_matches_central_differences():
    """The forward-mode Jacobian the joint LM uses (coupled simulation, all zones' parameters)
    against central differences."""
    lay, Th, f, per, rec, on, _, _ = _problem(T=120)
    fp = {**f, **{k: v[0] for k, v in per.items()}}
    sim = lambda th: M.simulate_full(th.reshape(Th.shape), jnp.asarray(on), fp, lay, jnp.asarray(rec)).reshape(-1)
    x = jnp.asarray(Th.reshape(-1))
    for g in ("log_a", "log_tauh", "log_k", "rad_share"):
        j = lay.sl(g).start + lay.size          # zone 2's parameter: it moves zone 1 through the coupling
        t = jnp.zeros_like(x).at[j].set(1.0)
        _, jv = jax.jvp(sim, (x,), (t,))
        h = 1e-4       # smaller steps meet the round-off of the squared matrix exponential
        fd = (sim(x + h * t) - sim(x - h * t)) / (2 * h)
        np.testing.assert_allclose(np.asarray(jv), np.asarray(fd), rtol=1e-4, atol=1e-5 * float(jnp.max(jnp.abs(jv))))
        assert float(jnp.max(jnp.abs(jv.reshape(-1, 2)[:, 0]))) > 1e-6      # zone 1 feels it
