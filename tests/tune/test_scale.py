"""The tuning path at the printer's own scale (16 zones) under a watchdog: `tune_report` runs
programs on two threads, and at 16 zones their batched factorisations (the plants' steady
states, 9 x 33 x 33 per batch of 3 plants x 3 scenarios, above jaxlib's chunking threshold)
once deadlocked XLA's CPU pool (`runtime.one_matrix_at_a_time`). A few steps of `pi_ff`,
`lqg` and `lqg_ff` (the observer-based loop with the schedule feed-forward: its own programs)
in a child process, which is killed once it has used no CPU for `IDLE_S`: a hang fails the
test instead of hanging the suite. One rollout, 120 s scenarios, no robustness or changed-powder plants: the
fewest programs that still take the threaded path with batched factorisations."""

from __future__ import annotations

import json
import math
import os
import sys

import pytest

from jthermo.cli.watchdog import Stalled, run_watched

#: the child's watchdog: seconds without CPU work (every thread asleep) before it is killed;
#: it needs about 90 CPU s (pi_ff, lqg, lqg_ff) on two cores, and however long a loaded machine
#: makes that
IDLE_S = 120

CHILD = r"""
import json, sys
import jax
jax.config.update("jax_enable_x64", True)
from jthermo import runtime
runtime.enable_cache()            # the suite's cache directory, through the environment
from jthermo.tune import tune_report
out = {}
for family in ("pi_ff", "lqg", "lqg_ff"):
    r = tune_report(family, plant="printer", zones=16, steps=2, rollouts=1, duration=120.0,
                    seed=11, check_robustness=False, changed_powder=None)
    out[family] = {k: r[k] for k in ("tuned_cost", "start_cost", "lambda_pi_cost", "zones",
                                     "steps", "improvement_percent")}
out["looped"] = runtime.looped_calls()
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def child():
    from jthermo import runtime

    env = dict(os.environ)
    if runtime.cache_dir() is not None:
        env[runtime.ENV_DIR] = str(runtime.cache_dir())
    try:
        r = run_watched([sys.executable, "-c", CHILD], IDLE_S, env=env)
    except Stalled as exc:
        pytest.fail(f"tune_report at 16 zones: {exc}")
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("family", ["pi_ff", "lqg", "lqg_ff"])
def test_tuning_at_16_zones_ends_with_a_finite_report(child, family):
    rep = child[family]
    assert rep["zones"] == 16 and rep["steps"] == 2
    for k in ("tuned_cost", "start_cost", "lambda_pi_cost", "improvement_percent"):
        assert math.isfinite(rep[k]), (k, rep)
    assert rep["tuned_cost"] > 0 and rep["lambda_pi_cost"] > 0


def test_the_path_met_batched_factorisations(child):
    """Not a vacuous pass: the programs held batched LAPACK calls, lowered one by one."""
    assert child["looped"] > 0
