"""Issue 12: the grey-box fit says which zones did not converge and by how much a further
Gauss–Newton step would still lower their cost."""

import numpy as np

from jthermo.identify.greybox import fit_greybox
from jthermo.identify.pem import EXPECTED_IMPROVEMENT_TOL

from .test_scale import _bed


def test_converged_flag_matches_zone_report():
    data, _, _ = _bed(n=3, T=900, seed=2)
    done = fit_greybox(data)
    assert done.converged and done.extra["zones_not_converged"] == []
    assert len(done.extra["expected_improvement"]) == 3
    assert max(done.extra["expected_improvement"]) < EXPECTED_IMPROVEMENT_TOL
    # two LM steps from the ARX start leave every zone short of its optimum
    short = fit_greybox(data, max_steps=2)
    assert not short.converged
    bad = short.extra["zones_not_converged"]
    assert bad and all(short.extra["expected_improvement"][i] >= EXPECTED_IMPROVEMENT_TOL
                       for i in bad)
    assert short.cost > done.cost
    np.testing.assert_array_less(np.asarray(done.extra["zone_costs"]),
                                 np.asarray(short.extra["zone_costs"]) * (1 + 1e-12))
