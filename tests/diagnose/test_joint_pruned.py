"""A wide joint model fits only each zone's strongest couplings (`joint.pruned_start`): the
others are held at their start, the Jacobian narrows and the tests count what is free."""

import dataclasses

import numpy as np

from jthermo.diagnose import joint as J
from jthermo.diagnose import mechanisms as M


def _case(n=6, T=400):
    rng = np.random.default_rng(0)
    lay = M.make_layout(n, n, 13)
    u = rng.uniform(0.0, 1.0, (T, n))
    y = 20.0 + np.cumsum(rng.standard_normal((T, n)), axis=0)
    # heater gains: own 1, the next zone's 0.3, the others 0.01 (a grid start's floor)
    gain = np.full((n, n), 0.01) + 0.99 * np.eye(n)
    for i in range(n - 1):
        gain[i, i + 1] = 0.3
    neutral = np.stack([M.initial_theta(lay, log_a=np.log(0.01), log_b=np.log(gain[i]), x0=20.0)
                        for i in range(n)])
    # per-zone exchanges: zone i's fit found one to the next zone (the last zone: to the first),
    # the rest tiny
    theta_k = neutral.copy()
    k = np.full((n, n - 1), 1e-7)
    for i in range(n):
        j = (i + 1) % n
        k[i, j if j < i else j - 1] = 1e-3      # row i's columns: the other zones in order
    theta_k[:, lay.sl("log_k")] = np.log(k)
    return lay, u, y, gain, neutral, theta_k


def test_pruned_model_keeps_own_gain_and_strongest_exchange_and_holds_the_rest():
    n = 6
    lay, u, y, _gain, neutral, theta_k = _case(n)
    keep, start = J.pruned_start(neutral, lay, u, y, theta_k)
    kb, kk = keep[:, lay.sl("log_b")], keep[:, lay.sl("log_k")]
    # own heater and the strong next-zone gain fitted, the floor gains held (at the grid's value)
    assert np.all(np.diag(kb) == 1) and np.all(kb[np.arange(n - 1), np.arange(1, n)] == 1)
    assert kb.sum() == n + n - 1
    np.testing.assert_array_equal(start[:, lay.sl("log_b")], neutral[:, lay.sl("log_b")])
    # a pair's exchange is one for both zones: each zone fits the two of its ring (its own fit's
    # and the one its previous zone found), started where the joint start has them; the others
    # are held at the per-zone fit's (tiny) values, not at the joint start's 5 % of the loss
    assert np.all(kk.sum(axis=1) == 2)
    for i in range(n):
        kept = {[j for j in range(n) if j != i][c] for c in np.flatnonzero(kk[i, :n - 1])}
        assert kept == {(i + 1) % n, (i - 1) % n}
    held = kk == 0
    np.testing.assert_array_equal(start[:, lay.sl("log_k")][held], theta_k[:, lay.sl("log_k")][held])
    np.testing.assert_array_equal(start[:, lay.sl("log_k")][~held], neutral[:, lay.sl("log_k")][~held])
    # every other group stays free
    others = [g for g, _, _ in lay.sections if g not in ("log_b", "log_k")]
    assert np.all(keep[:, lay.mask(others) > 0] == 1)


def test_pruned_widths_shrink_and_the_tests_count_what_is_free():
    n = 6
    lay, u, y, _gain, neutral, theta_k = _case(n)
    keep, _ = J.pruned_start(neutral, lay, u, y, theta_k)
    pool = ["lateral_conduction", "radiative_loss", "heat_accumulation"]
    full, pruned = J.joint_active(n, lay, "heater_lag", pool), J.joint_active(n, lay, "heater_lag", pool, keep)
    # zone parameters: n losses, n² -> 2n - 1 gains, n lags, n(n - 1) -> 2n exchanges, 3n body
    assert full == 4 * -(-(n * (1 + n + 1 + (n - 1) + 3) + 2 * n + 13 + 1) // 4)
    assert pruned == 4 * -(-(n + (2 * n - 1) + n + 2 * n + 3 * n + 2 * n + 13 + 1) // 4) < full
    assert J.restricted_active(n, lay, pool, keep) < J.restricted_active(n, lay, pool)
    fields = {f.name: None for f in dataclasses.fields(J.JointFits)}
    js = J.JointFits(**{**fields, "n": n, "lay": lay, "keep": keep})
    # the mask a joint fit gets frees the kept couplings only; the likelihood-ratio test's degrees
    # of freedom count the free exchanges, not n (n - 1)
    free = js.zone_mask(J.joint_groups(("heater_lag", "lateral_conduction"))).reshape(n, -1)
    np.testing.assert_array_equal(free[:, lay.sl("log_k")], keep[:, lay.sl("log_k")])
    assert free.sum() == n + (2 * n - 1) + n + 2 * n
    assert js.n_added("lateral_conduction") == 2 * n and js.n_added("heater_lag") == n
    unpruned = J.JointFits(**{**fields, "n": n, "lay": lay})
    assert unpruned.n_added("lateral_conduction") == n * (n - 1)
    np.testing.assert_array_equal(unpruned.zone_mask(("log_a", "log_b")),
                                  np.tile(lay.mask(("log_a", "log_b")), n))
