"""`fitting`'s calls spread over threads (`_run_spread`): every problem's fit is the one of a
single call, bit for bit, for the per-zone and the joint fits, with one problem per call or one
call per thread."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.diagnose import fitting as F
from jthermo.diagnose import mechanisms as M

from .test_fitting_answers import _problem

jax.config.update("jax_enable_x64", True)


def test_call_rows_deal_the_live_problems_in_turn_and_pad():
    rows = F.call_rows(np.array([5, 0, 5, 5, 0]), 2)
    np.testing.assert_array_equal(rows[0], [0, 3, 4])
    np.testing.assert_array_equal(rows[1], [2, 1, -1])
    every = np.concatenate(rows)
    np.testing.assert_array_equal(np.sort(every[every >= 0]), np.arange(5))
    assert [r.size for r in F.call_rows(np.ones(7), 3)] == [3, 3, 3]


def _one_call_and_spread(monkeypatch, fit, n_problems):
    """`fit()` in one call and spread over two threads: the same arrays, bit for bit, from as
    many compiled calls as the split makes."""
    calls, run = [], F.run_problems
    monkeypatch.setattr(F, "run_problems", lambda *a: calls.append(1) or run(*a))
    monkeypatch.setenv("JTHERMO_FIT_THREADS", "1")
    whole = fit()
    assert len(calls) == 1
    monkeypatch.setenv("JTHERMO_FIT_THREADS", "2")
    for size, n_calls in ((1, n_problems), (None, 2)):   # one problem per call (default), per thread
        monkeypatch.setattr(F, "CALL_SIZE", size)
        calls.clear()
        split = fit()
        assert len(calls) == n_calls
        assert len(whole) == len(split)
        for a, b in zip(whole, split):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_joint_fits_spread_equal_one_call(monkeypatch):
    Theta0, on, rec0, mask, y, w, per, f, lay = _problem()
    pad = jnp.asarray([0, 1, 2, 2, 0])                  # padded copies, as the callers make
    take = lambda x: x[pad]                             # noqa: E731
    args = (take(Theta0), take(on), take(rec0), take(mask), y, w, jax.tree_util.tree_map(take, per), f, lay)
    _one_call_and_spread(monkeypatch, lambda: F.fit_joint(*args, 20, 16), 5)


def test_zone_fits_spread_equal_one_call(monkeypatch):
    T, N, ts = 300, 3, 1.0
    rng = np.random.default_rng(4)
    u = np.repeat(rng.integers(0, 2, size=(T // 15 + 1, N)), 15, axis=0)[:T] * 0.8
    y = 30.0 + np.cumsum(0.05 * rng.standard_normal((T, N)), axis=0) + 3.0 * u
    lay = M.make_layout(N, N, M.n_drift_knots(T, ts))
    th0 = np.stack([M.initial_theta(lay, log_a=np.log(0.01), log_b=np.log([0.1] * N), x0=y[0, i])
                    for i in range(N)])
    mask = lay.mask(["log_a", "log_b", "x0"])
    shared = {"u": jnp.asarray(u), "ts_level": jnp.asarray(25.0), "ts_free": jnp.asarray(0.0),
              "wdev": jnp.zeros(T), "Phi": jnp.asarray(M.drift_basis(T, ts, lay.n_drift)),
              "u_pad": jnp.asarray(u.mean(axis=0)), "ts": jnp.asarray(ts), "t_ref": jnp.asarray(float(y.mean()))}
    per = {"y": jnp.asarray(y.T), "ynb": jnp.asarray(np.stack([np.delete(y, i, axis=1) for i in range(N)])),
           "ybar": jnp.asarray(np.tile(y.mean(axis=1), (N, 1))), "events": jnp.zeros((N, T)),
           "delay": jnp.zeros(N)}
    budget = np.array([40, 0, 25])                      # one problem with nothing to do
    _one_call_and_spread(monkeypatch, lambda: F.fit_zones(jnp.asarray(th0), jnp.asarray(np.tile(mask, (N, 1))),
                                                          jnp.zeros((N, 8)), per, shared, lay, 40,
                                                          int(mask.sum()), budget), N)


def test_thread_count_from_the_environment(monkeypatch):
    monkeypatch.setenv("JTHERMO_FIT_THREADS", "3")
    assert F.n_threads() == 3
    monkeypatch.setenv("JTHERMO_FIT_THREADS", "0")
    assert F.n_threads() == 1
    monkeypatch.delenv("JTHERMO_FIT_THREADS")
    default = F.n_threads()
    monkeypatch.setenv("JTHERMO_FIT_THREADS", "many")                 # not a count: the default
    assert F.n_threads() == default and 1 <= default <= F.MAX_THREADS


def test_one_thread_where_the_caller_is_not_the_main_thread(monkeypatch):
    from concurrent.futures import ThreadPoolExecutor

    monkeypatch.delenv("JTHERMO_FIT_THREADS", raising=False)
    with ThreadPoolExecutor(1) as pool:
        assert pool.submit(F.n_threads).result() == 1
    monkeypatch.setenv("JTHERMO_FIT_THREADS", "2")                    # the variable decides
    with ThreadPoolExecutor(1) as pool:
        assert pool.submit(F.n_threads).result() == 2
