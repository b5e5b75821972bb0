"""A stored-heat body's per-zone fit also starts slow (hard set 6 case 04: the neutral
start's fit ended at the shortest time constant allowed, 40 s, for a 1900 s body)."""

import numpy as np

from jthermo.diagnose import mechanisms as M
from jthermo.diagnose import starts as ST


def _lay():
    return M.make_layout(2, 2, 5)


def test_body_starts_set_the_effective_time_constant():
    lay = _lay()
    th = np.stack([M.initial_theta(lay, log_a=np.log(1 / 300), log_b=np.log([0.1, 0.1]), x0=40.0)] * 2)
    starts = ST.body_starts(th, lay, taus=(1500.0, 4000.0))
    assert len(starts) == 2
    for tau, s in zip((1500.0, 4000.0), starts):
        tauw, gam = M.wall_parameters(s[:, lay.sl("log_tauw")], s[:, lay.sl("log_gamma")])
        np.testing.assert_allclose(tauw / (1 + gam), tau, rtol=1e-12)
        # nothing else moves
        other = np.ones(lay.size, bool)
        other[lay.sl("log_tauw")] = False
        np.testing.assert_array_equal(s[:, other], th[:, other])


def test_best_of_starts_keeps_each_zones_smallest_cost():
    S, n, P, T = 4, 2, 3, 5          # candidates 0, 1; extra starts of candidate 1 at 2, 3
    theta = np.arange(S * n * P, dtype=float).reshape(S, n, P)
    resid = np.ones((S, T, n))
    resid[2, :, 0] = 0.1             # zone 0: extra start 2 is best
    resid[3, :, 1] = 0.2             # zone 1: extra start 3 is best
    resid[1, :, 1] = 0.5
    th, rs = ST.best_of_starts(theta, resid, 1, [2, 3])
    assert th.shape == (2, n, P) and rs.shape == (2, T, n)
    np.testing.assert_array_equal(th[1, 0], theta[2, 0])
    np.testing.assert_array_equal(th[1, 1], theta[3, 1])
    np.testing.assert_array_equal(rs[1, :, 0], resid[2, :, 0])
    np.testing.assert_array_equal(th[0], theta[0])       # other candidates untouched
    # a diverged start (non-finite cost) is never kept
    resid[2, 0, 0] = np.nan
    th, _ = ST.best_of_starts(theta, resid, 1, [2, 3])
    assert not np.array_equal(th[1, 0], theta[2, 0])
