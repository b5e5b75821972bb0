"""Issue 12 part 3: does the state-space PEM's focus explain its validation gap at scale?

On the records of `benchmarks/identification_scale.py` (seed 0), `fit_statespace` with
`focus="prediction"` (the default, K estimated) and `focus="simulation"` (K = 0), operating
point "mean", in-process (warm imports, compilation included); validation simulation fit next
to the true model's. Writes `experiments/results/ss_focus_scale.md`.

Usage: python experiments/ss_focus_scale.py [--n 4 16]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))


def main(argv=None) -> int:
    import identification_scale as S

    from jthermo.identify.statespace import fit_statespace
    from jthermo.validate import compare

    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="+", default=[4, 16])
    args = ap.parse_args(argv)
    lines = ["# ss focus at scale (`python experiments/ss_focus_scale.py --n "
             + " ".join(map(str, args.n)) + "`)", "",
             "| N | focus | seconds | converged | steps | val fit % | true fit % | gap |",
             "|---|---|---|---|---|---|---|---|"]
    for N in args.n:
        est, _ = S.record(N, S.T_EST, 0, 1)
        val, _ = S.record(N, S.T_VAL, 0, 2)
        truth = S.true_fit(N, 0, val)
        for focus in ("prediction", "simulation"):
            t = time.perf_counter()
            r = fit_statespace(est, focus=focus, operating_point="mean")
            sec = time.perf_counter() - t
            fit = compare(r.model, val)["mean_fit_percent"]
            lines.append(f"| {N} | {focus} | {sec:.1f} | {r.converged} | {r.extra['n_steps']} | "
                         f"{fit:.2f} | {truth:.2f} | {truth - fit:.2f} |")
            print(lines[-1], flush=True)
    up = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    lines += ["", f"uptime at the end: `{up}` (shared 2-core machine)"]
    out = ROOT / "experiments" / "results" / "ss_focus_scale.md"
    out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
