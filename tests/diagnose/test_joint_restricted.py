"""Large joint models fit their additions restricted (`joint.RESTRICT_ABOVE`): the smaller
model's zone parameters held but for the losses, the chosen addition refitted in full."""

import jax
import numpy as np

from jthermo.diagnose import diagnose
from jthermo.diagnose import joint as J
from jthermo.diagnose import select as S
from jthermo.printer import generate, make_printer

jax.config.update("jax_enable_x64", True)


def test_restricted_additions_hold_the_smaller_model(monkeypatch):
    """Forced on a 2-zone printer record (lag and conduction concealed): every restricted
    addition leaves the heater gains where the smaller model had them, the chosen one is
    refitted in full, and the diagnosis still names both effects."""
    p = make_printer(2, ("heater_lag", "lateral_conduction"), seed=0)
    est, val = generate(p, "prbs", 1500.0, seed=1), generate(p, "prbs", 750.0, seed=2)
    monkeypatch.setattr(S, "RESTRICT_ABOVE", 0)
    calls, fit = [], J.JointFits.fit

    def spy(self, models, validate, restricted=False):
        out = fit(self, models, validate, restricted)
        if restricted:
            calls.append([(np.array(m[0]), o["theta"], m[1][-1]) for m, o in zip(models, out)])
        return out

    monkeypatch.setattr(J.JointFits, "fit", spy)
    res = diagnose(est, val)
    assert calls, "no addition was fitted restricted"
    for call in calls:
        for start, theta, added in call:
            lay = J.M.make_layout(2, 2, theta.shape[1] - J.M.make_layout(2, 2, 0).size)
            assert added in J.M.MECHANISMS
            held = [g for g in J.joint_groups(()) + ("log_tauh", "log_k", "rad_share", "log_e")
                    if g != "log_a" and g not in J.M.MECH_PARAMS[added]]
            for g in held:
                np.testing.assert_array_equal(theta[:, lay.sl(g)], start[:, lay.sl(g)], err_msg=g)
    accepted = [c for c in res["combinations"] if c["accepted"]]
    assert accepted and all(c.get("refitted_in_full") for c in accepted)
    assert {"heater_lag", "lateral_conduction"} <= {f["mechanism"] for f in res["findings"]}
