"""The diagnosis fits' speed-ups keep their answers: models fitted one after another with the
Jacobian reused after rejected steps and an early stop (`fitting.RTOL`), padded copies not
refitted."""

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.diagnose import fitting as F
from jthermo.diagnose import mechanisms as M
from jthermo.identify.lm import masked_lm

jax.config.update("jax_enable_x64", True)

T, N = 200, 2


def _problem():
    """Two coupled zones with heater lag and radiation, three models (lag alone, lag + coupling,
    lag + radiation) from a perturbed start."""
    lay = M.make_layout(N, N, M.n_drift_knots(T, 1.0))
    rng = np.random.default_rng(3)
    u = np.repeat(rng.integers(0, 2, size=(T // 20 + 1, N)), 20, axis=0)[:T].astype(float)
    Th = np.stack([M.initial_theta(lay, log_a=np.log(0.006 + 0.001 * i), log_b=np.log([0.5, 0.05][::1 - 2 * i]),
                                   x0=22.0) for i in range(N)])
    Th[:, lay.sl("log_tauh")] = np.log([15.0, 12.0])[:, None]
    Th[:, lay.sl("log_k")] = np.log(0.002)
    f = {"u": jnp.asarray(u), "wdev": jnp.zeros(T), "Phi": jnp.asarray(M.drift_basis(T, 1.0, lay.n_drift)),
         "ts": 1.0, "t_ref": 40.0}
    rec = np.r_[np.full(2 * N, 22.0), np.zeros(lay.n_drift + 1)]
    one = {"events": np.zeros((T, N)), "delay": 0.0, "ts_level": 22.0, "ts_free": 0.0, "u_pad": np.zeros(N)}
    y = np.asarray(M.simulate_full(jnp.asarray(Th), jnp.asarray(M.on_vector(("heater_lag", "lateral_conduction",
                                                                                 "radiative_loss"))),
                                   {**f, **one}, lay, jnp.asarray(rec)))
    y = y + 0.05 * rng.standard_normal(y.shape)
    sets = [("heater_lag",), ("heater_lag", "lateral_conduction"), ("heater_lag", "radiative_loss")]
    groups = {"heater_lag": ("log_tauh",), "lateral_conduction": ("log_k",), "radiative_loss": ("rad_share",)}
    start = Th.copy()
    start[:, lay.sl("log_tauh")] = np.log(5.0)
    start[:, lay.sl("log_a")] += 0.3
    masks = []
    for st in sets:
        m = np.zeros(N * lay.size + rec.size)
        m[:N * lay.size] = np.tile(lay.mask(("log_a", "log_b") + sum((groups[s] for s in st), ())), N)
        m[N * lay.size:N * lay.size + N] = 1.0
        masks.append(m)
    S = len(sets)
    per = {k: jnp.asarray(np.stack([np.asarray(v, float)] * S)) for k, v in one.items()}
    return (jnp.asarray(np.stack([start] * S)), jnp.asarray(np.stack([M.on_vector(s) for s in sets])),
            jnp.asarray(np.stack([rec] * S)), jnp.asarray(np.stack(masks)), jnp.asarray(y), jnp.ones(T), per, f,
            lay)


@functools.partial(jax.jit, static_argnames=("lay", "n_iter", "n_active"))
def _vmapped_fixed(Theta0, on, rec0, mask, y, w, per, f, lay, n_iter, n_active):
    """The solve before: every model vmapped, exactly `n_iter` iterations each."""
    nP = Theta0[0].size

    def one(Th, o, r0, m, fp):
        g = {**f, **fp}
        res = lambda v: (w[:, None] * (y - M.simulate_full(v[:nP].reshape(Th.shape), o, g, lay, v[nP:]))).reshape(-1)
        return masked_lm(res, jnp.concatenate([Th.reshape(-1), r0]), m, n_iter, n_active)[1]

    return jax.vmap(one)(Theta0, on, rec0, mask, per)


def test_joint_fits_equal_the_vmapped_fixed_iterations_in_cost():
    args = _problem()
    _, _, _, c = F.fit_joint(*args, 30, 16)
    c_ref = _vmapped_fixed(*args, 30, 16)
    np.testing.assert_allclose(np.asarray(c), np.asarray(c_ref), rtol=1e-8)


def test_padded_copies_are_copied_not_refitted():
    Theta0, on, rec0, mask, y, w, per, f, lay = _problem()
    pad = jnp.asarray([0, 1, 2, 2, 1])                  # slots 3 and 4 repeat models 2 and 1
    take = lambda x: x[pad]
    padded = (take(Theta0), take(on), take(rec0), take(mask), y, w, jax.tree_util.tree_map(take, per), f, lay)
    np.testing.assert_array_equal(F.first_copies(*(padded[:4] + (padded[6],))), [0, 1, 2, 2, 1])
    out = F.fit_joint(*padded, 30, 16)
    ref = F.fit_joint(Theta0, on, rec0, mask, y, w, per, f, lay, 30, 16)
    for a, b in zip(out, ref):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b)[np.asarray(pad)])
    # a copy that differs in one entry is fitted on its own
    Theta1 = padded[0].at[3, 0, 0].add(0.01)
    assert F.first_copies(Theta1, *padded[1:4], padded[6])[3] == 3
