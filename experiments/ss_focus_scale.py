"""Does the state-space PEM's focus explain its validation gap at scale?

On the records of `benchmarks/identification_scale.py` (seed 0), `fit_statespace` with
`focus="prediction"` (K estimated) and `focus="simulation"` (K = 0, the default since this
study), operating point "mean", in-process (warm imports, compilation included); validation
simulation fit next to the true model's. `--real` runs the same two focuses on the real
recordings of `experiments/identify.py` (TCLab CACE SS 2/4, Kuntz–Rawlings SS 2/6, Kantor SS 2,
its options and validation: `identify.evaluate`). Writes `experiments/results/ss_focus_scale.md`
(`ss_focus_scale_real.md` with `--real`).

Usage: python experiments/ss_focus_scale.py [--n 4 16] [--real]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "experiments"))
FOCUSES = ("prediction", "simulation")


def bed_rows(ns: list[int]) -> list[str]:
    import identification_scale as S

    from jthermo.identify.statespace import fit_statespace
    from jthermo.validate import compare

    lines = ["| N | focus | seconds | converged | steps | val fit % | true fit % | gap |",
             "|---|---|---|---|---|---|---|---|"]
    for N in ns:
        est, _ = S.record(N, S.T_EST, 0, 1)
        val, _ = S.record(N, S.T_VAL, 0, 2)
        truth = S.true_fit(N, 0, val)
        for focus in FOCUSES:
            t = time.perf_counter()
            r = fit_statespace(est, focus=focus, operating_point="mean")
            sec = time.perf_counter() - t
            fit = compare(r.model, val)["mean_fit_percent"]
            lines.append(f"| {N} | {focus} | {sec:.1f} | {r.converged} | {r.extra['n_steps']} | "
                         f"{fit:.2f} | {truth:.2f} | {truth - fit:.2f} |")
            print(lines[-1], flush=True)
    return lines


def real_cases():
    """(name, orders, est, val) of the real recordings, as `experiments/identify.py` splits them."""
    import identify as I

    from jthermo import data as jdata
    from jthermo.data import from_arrays

    est, val = I._load("tclab_cace2020/id_2heaters"), I._load("tclab_cace2020/val_2heaters")
    yield "TCLab CACE 2020 (id→val)", (2,), est, val
    yield "TCLab CACE 2020 (id→val)", (4,), est, val
    est, val = jdata.split(I._load("tclab_rawlings/prbs_kr2022"), 0.5)
    yield "TCLab Kuntz–Rawlings 2022 (halves)", (2,), est, val
    yield "TCLab Kuntz–Rawlings 2022 (halves)", (6,), est, val
    d = I._load("tclab_kantor_cbe30338/step_q1_50_a")
    pre = 30   # as identify.py: 30 samples at rest prepended, so that the record holds the step
    d = from_arrays(np.concatenate([np.zeros((pre, d.n_inputs)), d.u]),
                    np.concatenate([np.repeat(d.y[:1], pre, axis=0), d.y]), d.ts,
                    input_names=d.input_names, output_names=d.output_names)
    yield "TCLab Kantor step a (estimation data)", (2,), d, d


def real_rows() -> list[str]:
    import identify as I

    lines = ["| data | n | focus | seconds | fit % per output | mean fit % |",
             "|---|---|---|---|---|---|"]
    for name, orders, est, val in real_cases():
        for focus in FOCUSES:
            r = I.evaluate(name, "ss", orders, est, val, focus=focus)
            fits = ", ".join(f"{f:.1f}" for f in np.atleast_1d(r.get("fit", [])))
            lines.append(f"| {name} | {orders[0]} | {focus} | {r.get('seconds', float('nan')):.1f} "
                         f"| {fits or r.get('error', '')} | {r.get('mean_fit', float('nan')):.1f} |")
            print(lines[-1], flush=True)
    return lines


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="+", default=[4, 16])
    ap.add_argument("--real", action="store_true", help="the real recordings instead of the bed")
    args = ap.parse_args(argv)
    if args.real:
        head = "# ss focus on real recordings (`python experiments/ss_focus_scale.py --real`)"
        lines, out = real_rows(), "ss_focus_scale_real.md"
    else:
        head = ("# ss focus at scale (`python experiments/ss_focus_scale.py --n "
                + " ".join(map(str, args.n)) + "`)")
        lines = bed_rows(args.n)
        out = "ss_focus_scale.md"
    up = subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    lines = [head, ""] + lines + ["", (f"uptime at the end: `{up}` (shared 2-core machine: "
                                  "wall times are inflated by the load)")]
    (ROOT / "experiments" / "results" / out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
