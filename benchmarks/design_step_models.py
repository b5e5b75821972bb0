"""`control.rules.step_models` with its early stop (the step responses end once every diagonal
one crossed 63.2 % of its gain) against the whole horizon, on the printer's design models
(`cli.control.stored_printer_model`, 1-16 zones, printer seeds 0 and 3, with and without a coupled
input transform W): equal K, L, T bit for bit, and the seconds each takes.

    python benchmarks/design_step_models.py      # -> results/design_step_models.md
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from jthermo import runtime

HERE = Path(__file__).resolve().parent


def _full_horizon(R, ss, W):
    A, B, C, D = (np.asarray(q, np.float64) for q in (ss.A, ss.B, ss.C, ss.D))
    if W is not None:
        B, D = B @ W, D @ W
    n = R.step_horizon(ss)
    S = R.step_responses(A, B, C, D, n)
    G0 = C @ np.linalg.solve(np.eye(A.shape[0]) - A, B) + D
    out = [R.fit_step_model(S[:, i, i], ss.ts, G0[i, i]) for i in range(S.shape[1])]
    return [np.array(v) for v in zip(*out)], n


def main() -> None:
    runtime.enable_cache()
    runtime.unroll_threefry()
    import jax

    jax.config.update("jax_enable_x64", True)
    import jthermo.closedloop  # noqa: F401  (REALISTIC_EFFECTS)
    from jthermo.cli.control import stored_printer_model
    from jthermo.closedloop import REALISTIC_EFFECTS
    from jthermo.printer import make_printer

    R = sys.modules["jthermo.control.rules"]
    rows = ["| zones | printer seed | W | horizon samples | equal | early stop s | whole horizon s |",
            "|---|---|---|---|---|---|---|"]
    for z in (1, 4, 9, 16):
        for seed in (0, 3):
            m = stored_printer_model(make_printer(z, REALISTIC_EFFECTS, powder="PA12", seed=seed))
            ss = R.as_state_space(m)
            rng = np.random.default_rng(z)
            for W in (None, np.eye(z) + 0.1 * rng.standard_normal((z, z))):
                t0 = time.perf_counter()
                new = R.step_models(m, W)
                t1 = time.perf_counter()
                old, n = _full_horizon(R, ss, W)
                t2 = time.perf_counter()
                same = all(np.array_equal(a, b) for a, b in zip(old, new))
                rows.append(f"| {z} | {seed} | {'coupled' if W is not None else 'I'} | {n} | "
                            f"{'yes' if same else 'NO'} | {t1 - t0:.4f} | {t2 - t1:.4f} |")
    load = Path("/proc/loadavg").read_text().split()[0]
    text = "\n".join(["# `step_models`: early stop against the whole horizon", "",
                      "`python benchmarks/design_step_models.py` (1-minute load "
                      f"{load}; the whole-horizon column includes the crossing fits).", "",
                      *rows]) + "\n"
    (HERE / "results" / "design_step_models.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
