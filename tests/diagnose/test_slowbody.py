"""A slow stored-heat body is started from the fitted drift restricted to a body's
form (`slowbody.body_from_drift`), and a drift that does not out-predict a body with fewer
re-estimated parameters does not go ahead of it (`bodydrift.prefer_fewer_slow`)."""

import math

import numpy as np

from jthermo.diagnose import bodydrift as BD
from jthermo.diagnose import decide as D
from jthermo.diagnose import mechanisms as M
from jthermo.diagnose.slowbody import body_from_drift

TS, T = 2.0, 1800          # one hour


def _drift_theta(lay, drift_knots, a):
    th = M.initial_theta(lay, log_a=math.log(a), log_b=np.zeros(lay.nu), x0=50.0)
    th[lay.sl("drift")] = drift_knots
    return th[None]


def test_body_start_recovers_the_body_a_drift_stands_for():
    """A drift that is exactly a body's (c/a) W(t), sampled at the knots, gives back the body's
    time constant, share and wall state."""
    kn = M.n_drift_knots(T, TS)
    lay = M.make_layout(1, 1, kn)
    Phi = M.drift_basis(T, TS, kn)
    t = np.arange(T) * TS
    level, a, c, tau, gam, w0 = 20.0, 1 / 400.0, 0.4 / 400.0, 2400.0, 1.0, -8.0
    rng = np.random.default_rng(0)
    ybar = level + 40.0 + 10.0 * (rng.random(T // 300).repeat(300) - 0.5)
    W = BD.lag_filter(ybar - level, TS, tau) / (1 + gam) + w0 * np.exp(-t / tau)
    knots = (c / a) * W[np.minimum(np.arange(kn) * int(M.DRIFT_SPACING / TS), T - 1)]
    th = body_from_drift(_drift_theta(lay, knots, a), ybar, Phi, level, 1.0, TS, lay,
                         taus=[600.0, 1200.0, 2400.0, 4800.0])
    tauw, g = M.wall_parameters(th[0, lay.sl("log_tauw")][0], th[0, lay.sl("log_gamma")][0])
    assert abs(g - 1.0) < 1e-12 and abs(tauw / (1 + g) - 2400.0) < 1e-6
    cf, af = math.exp(th[0, lay.sl("log_c")][0]), math.exp(th[0, lay.sl("log_a")][0])
    assert abs(af + cf - a) < 1e-12                      # the zone's total loss is the drift fit's
    assert abs(cf / a - 0.4) < 0.05
    assert abs(th[0, lay.sl("xw0")][0] - w0) < 1.0


def test_no_body_start_from_a_falling_drift():
    """A drift that falls as the zones warm is nothing a body the zones heat explains."""
    kn = M.n_drift_knots(T, TS)
    lay = M.make_layout(1, 1, kn)
    ybar = 60.0 + np.linspace(0.0, 20.0, T)
    knots = -np.linspace(0.0, 3.0, kn)
    assert body_from_drift(_drift_theta(lay, knots, 1 / 400.0), ybar, M.drift_basis(T, TS, kn), 20.0, 1.0,
                           TS, lay, taus=[600.0, 2400.0]) is None


def test_a_drift_not_beating_the_body_goes_behind_it():
    rows = [{"mechanism": m} for m in ("ambient_variation", "radiative_loss", "heat_accumulation")]
    names = lambda rs: [r["mechanism"] for r in rs]
    assert names(BD.prefer_fewer_slow(rows, 1.0, 2, 7)) == ["heat_accumulation", "ambient_variation",
                                                           "radiative_loss"]
    assert names(BD.prefer_fewer_slow(rows, 2.0, 2, 7)) == names(rows)       # the drift beats it
    assert names(BD.prefer_fewer_slow(rows, 1.0, 7, 7)) == names(rows)       # not fewer parameters
    assert names(BD.prefer_fewer_slow(rows[:2], 0.0, 2, 7)) == names(rows[:2])


def test_a_drift_not_fitting_the_estimation_record_better_goes_behind_the_body():
    """`slowbody.order_by_estimation`: on the estimation record both are charged every parameter;
    a drift whose residual is no smaller than the body's, beyond the parameters it adds, goes
    behind it (`bodydrift.prefer_input_driven`); one that fits clearly better keeps its place."""
    from jthermo.diagnose.slowbody import order_by_estimation

    rng = np.random.default_rng(3)
    e_body = rng.normal(0.0, 0.1, (1800, 3))
    tied = e_body + rng.normal(0.0, 0.002, e_body.shape)       # the same misfit, a little noise
    better = 0.8 * e_body                                       # the drift explains a fifth more
    cands = ["ambient_variation", "heat_accumulation", "radiative_loss"]
    rows = [{"mechanism": m} for m in ("ambient_variation", "radiative_loss", "heat_accumulation")]
    names = lambda rs: [r["mechanism"] for r in rs]
    dof = {"ambient_variation": 13, "heat_accumulation": 12, "radiative_loss": 3}.get
    for e_drift, order in ((tied, ["heat_accumulation", "ambient_variation", "radiative_loss"]),
                           (better, names(rows))):
        loc = {}
        res = [e_drift, e_body, e_body]
        assert names(order_by_estimation(rows, res, cands, dof, loc)) == order
        assert D.is_rival(loc["drift_over_body_estimation_z"]) == (e_drift is tied)
    assert names(order_by_estimation(rows, [e_body] * 2, cands[1:], dof, {})) == names(rows)
    assert names(BD.prefer_input_driven(rows, 1.0)) == ["heat_accumulation", "ambient_variation",
                                                        "radiative_loss"]
    assert names(BD.prefer_input_driven(rows, 2.0)) == names(rows)
