"""The dead-time scan refits the baseline at its best delay (`prepare.scan_delay`): a baseline
fitted with no dead time has taken part of one up in its rates and gains, and simulated with a
delay it fits best a sample short of the truth, beyond the reach of the `input_delay`
candidate's fit (a sample either side of the scan's best)."""

import jax.numpy as jnp
import numpy as np

from jthermo.diagnose import select as S
from jthermo.diagnose.checks import as_records, pool_records
from jthermo.diagnose.prepare import fit_baseline_stage, localise_stage, prepare
from jthermo.printer import generate, make_printer


def _scan(n, delay_s, seed, capacity, refits):
    p = make_printer(n, {"input_delay": {"delay_s": delay_s}, "sensor_noise": {}}, seed=seed,
                     capacity=jnp.full(n, capacity))
    est = generate(p, "prbs", 3600.0, seed=seed + 11)
    val = generate(p, "prbs", 600.0, seed=seed + 12)
    recs, e, v, _ = pool_records(as_records(est), val, S.TS_TOLERANCE)
    pb = prepare(recs, e, v, ("input_delay",))
    base = fit_baseline_stage(pb)
    return [localise_stage(pb, base, S.MAX_DELAY, S.MAX_DELAY_S, S.DELAY_STEP, r).delay for r in refits]


def test_refitted_scan_finds_a_pure_dead_time_the_fixed_baseline_misses():
    """Four 19-20 s zones behind a 5 s dead time (Ts = 1 s): the fixed baseline's scan says 4 s,
    refitted it says 5 s."""
    fixed, refined = _scan(4, 5, 11, 4.0, (0, S.DELAY_REFITS))
    assert fixed <= 4.0
    assert refined == 5.0


def test_refitted_scan_one_zone():
    fixed, refined = _scan(1, 6, 12, 6.0, (0, S.DELAY_REFITS))
    assert abs(refined - 6.0) <= abs(fixed - 6.0) and refined == 6.0
