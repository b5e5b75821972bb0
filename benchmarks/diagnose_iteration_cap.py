"""What the per-zone iteration cap (`select.N_ITER`) costs: the latency record (1 h, 4 zones;
30 min validation; `benchmarks/diagnose_profile.py`) diagnosed in one process at each cap, the
caps interleaved over `--repeats` rounds after a first (compiling) call of each, CPU s (user +
system, all threads: the load-robust figure) and wall s, findings and augmented fit.

    python benchmarks/diagnose_iteration_cap.py --caps 60,200 [--repeats 2] [--tag _s33]

Writes `benchmarks/results/diagnose_iteration_cap{tag}.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
sys.path.insert(0, str(HERE))
from diagnose_profile import _cpu, _load, write_record

from jthermo import data
from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose, to_json


def one(est, val, cap: int) -> dict:
    t0, c0 = time.perf_counter(), _cpu()
    res = to_json(diagnose(est, val, n_iter=cap))
    return {"cap": cap, "wall_s": time.perf_counter() - t0, "cpu_s": _cpu() - c0,
            "findings": [(f["mechanism"], f["confidence"]) for f in res["findings"]],
            "augmented_fit": res["augmented"]["mean_fit_percent"] if res.get("augmented") else None,
            "load": _load()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--caps", default="60,200")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--tag", default="")
    args = ap.parse_args(argv)
    caps = [int(c) for c in args.caps.split(",")]
    with tempfile.TemporaryDirectory() as tmp:
        e, v = write_record(Path(tmp))
        est, val = data.load(e), data.load(v)
        first = [one(est, val, c) for c in caps]
        runs = [one(est, val, c) for _ in range(args.repeats) for c in caps]
    rows = []
    for c in caps:
        r = [x for x in runs if x["cap"] == c]
        f = next(x for x in first if x["cap"] == c)
        rows.append({"cap": c, "first_cpu_s": f["cpu_s"], "cpu_s": float(np.median([x["cpu_s"] for x in r])),
                     "wall_s": float(np.median([x["wall_s"] for x in r])), "findings": r[0]["findings"],
                     "augmented_fit": r[0]["augmented_fit"], "loads": [x["load"] for x in r]})
    lines = [f"# Per-zone iteration cap of the diagnosis{args.tag}", "",
             f"`python benchmarks/diagnose_iteration_cap.py --caps {args.caps} --repeats {args.repeats}"
             f"{' --tag ' + args.tag if args.tag else ''}`: the latency record diagnosed in one process, "
             "the caps interleaved after a first call of each; medians of the repeats (CPU s = user + "
             "system of the process, all threads; wall s inflated by the load of 2 shared cores).", "",
             "| cap | first call CPU s | CPU s | wall s | findings | augmented fit % | loads |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        names = ", ".join(f"{m} {c}" for m, c in r["findings"]) or "-"
        fit = f"{r['augmented_fit']:.4f}" if r["augmented_fit"] is not None else "-"
        lines.append(f"| {r['cap']} | {r['first_cpu_s']:.1f} | {r['cpu_s']:.1f} | {r['wall_s']:.1f} | {names} | "
                     f"{fit} | {', '.join(f'{x:.1f}' for x in r['loads'])} |")
    RESULTS.mkdir(exist_ok=True)
    atomic_write_text(RESULTS / f"diagnose_iteration_cap{args.tag}.md", "\n".join(lines) + "\n")
    atomic_write_text(RESULTS / f"diagnose_iteration_cap{args.tag}.json",
                      json.dumps({"rows": rows, "first": first, "runs": runs}, indent=1))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
