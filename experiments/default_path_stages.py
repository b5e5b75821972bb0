"""Where the default path's memory and time go after the PEM: the fit's guard check
(`check_model`, simulation on the estimation record) and `compare` (validation fit with the
initial state estimated by least squares over the Jacobian of `simulate(u, x0)`), for an
OE- and a BJ-shaped polynomial model with MATLAB's per-pair F at N zones (nx = N·N·nf + noise
states). Peak RSS (ru_maxrss, cumulative within the process) after each stage, one fresh
process per model; W1 records of `benchmarks/identification.py` (6000 + 3000 samples).

Usage: python experiments/default_path_stages.py --n 16 19 [--out PATH]
Writes experiments/results/default_path_stages.md (default). That table was measured with the
dense realisation in `Polynomial.simulate(u, x0)` (models code of commit 346019c);
`default_path_stages_blocks.md` with its per-block free response, and
`default_path_stages_dense.md` (`--dense`: the dense realisation checked and compared) in the
same run, for times at the same load.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "results" / "default_path_stages.md"


def _mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child(N: int, shape: str, dense: bool) -> None:
    import numpy as np

    sys.path.insert(0, str(ROOT / "benchmarks"))
    from identification import load_workloads

    from jthermo.data import from_arrays
    from jthermo.identify.guard import check_model
    from jthermo.models.polynomial import Polynomial
    from jthermo.validate import compare

    W = load_workloads()
    est, val = W.make_dataset(N, 6000, 0, 1), W.make_dataset(N, 3000, 0, 2)
    e, v = from_arrays(est["u"], 25.0 + est["y"]), from_arrays(val["u"], 25.0 + val["y"])
    rng = np.random.default_rng(0)
    noise = {"c": 0.1 * np.ones((N, 2)), "d": -0.1 * np.ones((N, 2))} if shape == "bj" else {}
    m = Polynomial(b=0.01 * rng.random((N, N, 1)), f=-0.9 + 0.05 * rng.random((N, N, 1)), nk=1,
                   u0=np.zeros(N), y0=25.0 * np.ones(N), **noise)
    if dense:   # the dense realisation (what Polynomial.simulate(u, x0) used before 815468a)
        m = m.to_statespace()
    row = {"N": N, "shape": shape, "nx": int((m if dense else m.to_statespace()).A.shape[0]),
           "data_mb": _mb()}
    t = time.perf_counter()
    check_model(m, e)
    row.update(check_s=time.perf_counter() - t, check_mb=_mb())
    t = time.perf_counter()
    compare(m, v)
    row.update(compare_s=time.perf_counter() - t, compare_mb=_mb())
    print(json.dumps(row))


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        child(int(argv[1]), argv[2], argv[3] == "dense")
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[16, 19])
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--dense", action="store_true",
                    help="check and compare the model's dense state-space realisation instead")
    args = ap.parse_args(argv)
    lines = ["# Default path after the PEM: guard check and validation compare", "",
             ("`python experiments/default_path_stages.py " + " ".join(argv) + "`. Peak RSS "
              "(cumulative) after loading the data, after `check_model` on the estimation record, "
              "after `compare` on the validation record; times are inflated by the load (1-minute "
              "load average, 2-core machine shared with other jobs)."), "",
             "| N | model | nx | data MB | check s | check MB | compare s | compare MB | load |",
             "|---|---|---|---|---|---|---|---|---|"]
    for N in args.n:
        for shape in ("oe", "bj"):
            p = subprocess.run([sys.executable, __file__, "--child", str(N), shape,
                                "dense" if args.dense else "blocks"], check=True,
                               capture_output=True, text=True, cwd=ROOT)
            r = json.loads(p.stdout.strip().splitlines()[-1])
            lines.append(f"| {N} | {shape} | {r['nx']} | {r['data_mb']:.0f} | {r['check_s']:.1f} | "
                         f"{r['check_mb']:.0f} | {r['compare_s']:.1f} | {r['compare_mb']:.0f} | "
                         f"{os.getloadavg()[0]:.1f} |")
            args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
