"""Issue 12: should `ss` use its one-state-per-output structure (diagonal A first, x0 and the
output level estimated) when the operating point is "rest"? (Today rest mode means x0 = 0 and
goes to the full-A PEM.) Measured on the records it would change: real recordings with n = ny
(`ss_focus_scale.real_cases`, ss 2) and W1's default-path records at N = 16 (held-back seed
31, sensor noise std 0.15 °C, pole 0.8: `identification.py --default-path` records).

Variants of `fit(data, "ss", orders)`: the default; `estimate_x0=True` (the structured path in
rest mode, as tried in 332480b); `coupling="full", estimate_x0=True` (full A, x0 estimated).
Validation: `compare` (initial state estimated); the recordings with `experiments/identify.py`'s
ss options (`SS_OPTS`, as `identify.evaluate`). CPU s in-process (compilation included where
first).

    python experiments/ss_rest_structure.py
    -> experiments/results/ss_rest_structure.md
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "experiments"))
VARIANTS = (("default", {}), ("estimate_x0=True", {"estimate_x0": True}),
            ("full A, estimate_x0=True", {"coupling": "full", "estimate_x0": True}))


def cases():
    """(name, orders, est, val, true fit or None): W1 N = 16 held-back and the n = ny recordings."""
    import identification as B
    from ss_focus_scale import real_cases

    from jthermo.data import from_arrays

    W = B.with_noise(B.load_workloads(), 0.15, 0.8)
    est, val = W.make_dataset(16, 6000, 31, 1), W.make_dataset(16, 3000, 31, 2)
    yield ("W1 N=16 seed 31 (noise 0.15/0.8)", None, from_arrays(est["u"], 25.0 + est["y"]),
           from_arrays(val["u"], 25.0 + val["y"]), W.fit_percent(val["y"], val["y_clean"]))
    for name, orders, e, v in real_cases():
        if orders is not None and orders[0] == e.n_outputs:
            yield name, orders, e, v, None


def main() -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    import identify as I

    from jthermo.identify.fit import fit
    from jthermo.validate import compare

    out = ROOT / "experiments" / "results" / "ss_rest_structure.md"
    lines = ["# ss in rest mode: one state per output with x0 estimated, or x0 = 0 and full A", "",
             "`python experiments/ss_rest_structure.py`; operating point and coupling as "
             "fitted; fit % = validation (`compare`, initial state estimated; W1 with the gap "
             "to the true model; recordings with `experiments/identify.SS_OPTS`).", "",
             "| data | variant | operating point | coupling | mean fit % | gap | CPU s | load |",
             "|---|---|---|---|---|---|---|---|"]
    for name, orders, est, val, truth in cases():
        for label, kw in VARIANTS:
            t0 = time.process_time()
            opts = {**(I.SS_OPTS if truth is None else {}), **kw}
            res = fit(est, "ss", orders, seed=0, **opts)
            fitp = compare(res.model, val)["mean_fit_percent"]
            op, coupling = res.extra.get("operating_point"), res.extra.get("coupling")
            cpu = time.process_time() - t0
            gap = f"{fitp - truth:+.2f}" if truth is not None else "—"
            lines.append(f"| {name} | {label} | {op} | {coupling} | {fitp:.2f} | {gap} | "
                         f"{cpu:.1f} | {os.getloadavg()[0]:.1f} |")
            print(lines[-1], flush=True)
            out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
