"""Zone fits still falling at their iteration cap are continued (held-out set 21 case 84:
a 7-zone saturating lamp named `radiative_loss` at 0.999 against a lamp fit whose heater
gains revive only after 200-800 iterations)."""

import numpy as np

import jthermo.diagnose.candidates as C
import jthermo.diagnose.select as S
from jthermo.diagnose import diagnose
from jthermo.diagnose.fitting import FALL_LR, FALL_WINDOW, fit_zones, still_falling
from tests.diagnose.test_mechanisms_gain_starts import lamp_record


def test_still_falling_reads_the_fall_in_likelihood_ratio_units():
    m, W = 1000, FALL_WINDOW
    flat = np.full((1, 60), 0.5)                                   # stopped on RTOL: repeats its cost
    slow = 0.5 * np.exp(-np.arange(60) * (0.5 * FALL_LR / (m * W)))[None]   # half a unit over W
    fast = 0.5 * np.exp(-np.arange(60) * (2.0 * FALL_LR / (m * W)))[None]   # two units over W
    bad = np.full((1, 60), np.inf)
    got = still_falling(np.concatenate([flat, slow, fast, bad]), m)
    assert got.tolist() == [False, False, True, False]


def test_zone_fits_still_falling_at_the_cap_are_continued(monkeypatch):
    """At a cap of 5 iterations the two-zone lamp record's lamp fits are still falling: with the
    continuation rounds the diagnosis calls the zone fits again for those problems only, and
    their estimation cost ends lower than without (rounds 0: the code before)."""
    est, val = lamp_record()
    calls = []

    def spy(*a):
        calls.append(np.asarray(a[8]) if len(a) > 8 else None)
        return fit_zones(*a)

    monkeypatch.setattr(C, "fit_zones", spy)
    sse = lambda r: float(np.sum(r["_arrays"]["resid_est_candidates"]["input_nonlinearity"] ** 2))
    run = lambda: diagnose(est, val, mechanisms=("input_nonlinearity",), n_iter=5)
    cont = run()
    budgets = [b for b in calls if b is not None]
    assert budgets and all(set(np.unique(b)) <= {0, 5} for b in budgets) and budgets[0].any()
    monkeypatch.setattr(S, "CONTINUE_ROUNDS", 0)
    calls.clear()
    once = run()
    assert all(b is None for b in calls)
    assert sse(cont) < 0.98 * sse(once)
