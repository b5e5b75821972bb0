"""Should `ss` use its one-state-per-output structure (diagonal A first) when the
operating point is "rest"? (Today rest mode means x0 = 0 and goes to the full-A PEM.) Measured
on the records it would change: real recordings with n = ny (`ss_focus_scale.real_cases`,
ss 2) and W1's default-path records (`identification.py --default-path` records) at
N = 4 / 9 / 16, seed 0 (default noise) and held-back seed 31 (sensor noise std 0.15 °C, pole
0.8).

Variants of `fit(data, "ss", orders)` (`--variants`): `default`; `estimate_x0=True` (the
structured path in rest mode with x0 estimated, as tried in 332480b and reverted); `full A,
estimate_x0=True`; `rest_coupling=auto` (diagonal A with x0 = 0 in rest mode, full A when the
held-back-third check favours it; the default since it was measured, after fd8d1c6);
`rest_coupling=diagonal`; `rest_coupling=full` (the earlier default: full A, x0 = 0).
Validation: `compare` (initial state estimated); the recordings with `experiments/identify.py`'s
ss options (`SS_OPTS`, as `identify.evaluate`). CPU s in-process (compilation included where
first).

    python experiments/ss_rest_structure.py --variants default rest_coupling=auto
        --out ss_rest_diagonal_x0zero.md
    -> experiments/results/<out>  (default ss_rest_structure.md, all variants but the last two)
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
VARIANTS = {"default": {}, "estimate_x0=True": {"estimate_x0": True},
            "full A, estimate_x0=True": {"coupling": "full", "estimate_x0": True},
            "rest_coupling=auto": {"rest_coupling": "auto"},
            "rest_coupling=diagonal": {"rest_coupling": "diagonal"},
            "rest_coupling=full": {"rest_coupling": "full"}}


def cases(w1: list[tuple[int, int]]):
    """(name, orders, est, val, true fit or None): W1 records (N, seed) and the n = ny
    recordings."""
    import identification as B
    from ss_focus_scale import real_cases

    from jthermo.data import from_arrays

    for n, seed in w1:
        W = B.with_noise(B.load_workloads(), 0.15, 0.8) if seed == 31 else B.load_workloads()
        est, val = W.make_dataset(n, 6000, seed, 1), W.make_dataset(n, 3000, seed, 2)
        label = f"W1 N={n} seed {seed}" + (" (noise 0.15/0.8)" if seed == 31 else "")
        yield (label, None, from_arrays(est["u"], 25.0 + est["y"]),
               from_arrays(val["u"], 25.0 + val["y"]), W.fit_percent(val["y"], val["y_clean"]))
    for name, orders, e, v in real_cases():
        if orders is not None and orders[0] == e.n_outputs:
            yield name, orders, e, v, None


def main(argv=None) -> int:
    import argparse

    import jax

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--variants", nargs="+", choices=list(VARIANTS),
                    default=list(VARIANTS)[:3])
    ap.add_argument("--w1", nargs="+", default=["16:31"],
                    help="W1 records as N:seed (seed 31: noise 0.15/0.8)")
    ap.add_argument("--out", default="ss_rest_structure.md")
    args = ap.parse_args(argv)
    w1 = [tuple(int(v) for v in s.split(":")) for s in args.w1]

    jax.config.update("jax_enable_x64", True)
    import identify as I

    from jthermo.identify.fit import fit
    from jthermo.validate import compare

    out = ROOT / "experiments" / "results" / args.out
    cmd = " ".join(["python experiments/ss_rest_structure.py", *(argv or sys.argv[1:])])
    lines = ["# ss in rest mode: which structure and initial state", "",
             (f"`{cmd}`; operating point and coupling as "
              "fitted; fit % = validation (`compare`, initial state estimated; W1 with the gap "
              "to the true model; recordings with `experiments/identify.SS_OPTS`)."), "",
             "| data | variant | operating point | coupling | mean fit % | gap | CPU s | load |",
             "|---|---|---|---|---|---|---|---|"]
    for name, orders, est, val, truth in cases(w1):
        for label in args.variants:
            kw = VARIANTS[label]
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
