"""W1 N4SID fit % and time against the subspace weighting (CVA, MOESP), the Hankel horizon
(block rows; None = `default_horizon`, 20 here) and the operating point (data means; rest at
zero input with the level estimated; rest at W1's known level 0 °C, as SIPPY assumes), N = 4 and
16: what the N4SID gap to SIPPY (benchmarks/results/identification.md) depends on.

    .venv/bin/python experiments/n4sid_horizon_check.py

Writes experiments/results/n4sid_horizon_check.md.
"""
import datetime
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import identification as bi  # noqa: E402

from jthermo.data import from_arrays  # noqa: E402
from jthermo.identify.subspace import n4sid  # noqa: E402

SIPPY = {4: 55.11, 16: 57.72}
OPERATING_POINTS = {"mean": {"operating_point": "mean"}, "rest": {"operating_point": "rest"},
                    "rest, level 0 given": {"rest_level": 0.0}}   # SIPPY N4SID (f = 20, raw data), benchmarks/results/identification.md


def main():
    W = bi.load_workloads()
    rows = []
    for N in (4, 16):
        est, val = W.estimation_validation(N, 6000)
        d = from_arrays(est["u"], est["y"])
        for op, kw in OPERATING_POINTS.items():
            for wt in ("cva", "moesp"):
                for h in (None, 10, 20, 30):
                    n4sid(d, N, h, weighting=wt, **kw)
                    t0 = time.perf_counter()
                    m = n4sid(d, N, h, weighting=wt, **kw)[0]
                    sec = time.perf_counter() - t0
                    f = W.fit_percent(val["y"], bi.simulate_from_rest(m, val["u"]))
                    rows.append(f"| {N} | {op} | {wt} | {'—' if h is None else h} | {f:.3f} | {sec:.3f} |")
                    print(rows[-1], flush=True)
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    text = "\n".join([
        "# W1: N4SID fit % by operating point, weighting and horizon", "",
        f"Command: `.venv/bin/python experiments/n4sid_horizon_check.py` ({stamp}, one BLAS "
        "thread). Validation simulation fit % from rest, mean over outputs; s = warm time of "
        f"one `n4sid` call. SIPPY N4SID (f = 20 block rows, raw data, i.e. level known): "
        f"{SIPPY[4]} (N = 4), {SIPPY[16]} (N = 16); oracle 55.5 / 58.8. Horizon — = the "
        "default (`default_horizon`: 20 here).", "",
        "| N | operating point | weighting | horizon | fit % | s |", "|---|---|---|---|---|---|",
        *rows, ""])
    (ROOT / "experiments" / "results" / "n4sid_horizon_check.md").write_text(text)


if __name__ == "__main__":
    main()
