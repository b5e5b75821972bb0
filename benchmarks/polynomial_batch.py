"""ARMAX / OE / BJ fits with the output rows solved together (`batch="vmap"`) or one after
another (`batch="map"`, the default): same results, peak memory and wall time.

`fit_polynomial` solves one MISO problem per output (outputs do not share parameters). With
`vmap` every output row and every start point is one lane of a batched Levenberg–Marquardt
loop, so all $n_y K$ Jacobians $(T, p)$ and their intermediates are held at once; with `map`
(`lax.map`, the same compiled call) only one. Each row runs in a fresh process with an empty
compilation cache (cold: compilation included); wall and peak RSS from /usr/bin/time;
W1 records in absolute °C (6000 estimation + 3000 validation samples, seed 0), the
validation simulation fit as `jthermo fit --validation` reports it.

Usage:
    python benchmarks/polynomial_batch.py --n 4 --orders auto     # the default path's orders
    python benchmarks/polynomial_batch.py --n 16 --orders true    # W1's true orders
Writes benchmarks/results/identification_default_batch_n<N>_<orders>.md/.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
FAMILIES = ("armax", "oe", "bj")
#: W1's true orders (first order per zone, one-sample delay), MATLAB's naming
TRUE_ORDERS = {"armax": (1, 1, 1, 1), "oe": (1, 1, 1), "bj": (1, 1, 1, 1, 1)}


def child(N: int, family: str, batch: str, orders: str) -> None:
    """One fit in this (fresh) process; prints a JSON line."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from identification import load_workloads

    from jthermo.data import from_arrays
    from jthermo.identify.fit import fit
    from jthermo.validate import compare

    W = load_workloads()
    est, val = W.make_dataset(N, 6000, 0, 1), W.make_dataset(N, 3000, 0, 2)
    e, v = from_arrays(est["u"], 25.0 + est["y"]), from_arrays(val["u"], 25.0 + val["y"])
    t0 = time.perf_counter()
    res = fit(e, family, TRUE_ORDERS[family] if orders == "true" else None, batch=batch)
    seconds = time.perf_counter() - t0
    cmp = compare(res.model, v)
    print(json.dumps({"orders": res.orders, "fit": float(cmp["mean_fit_percent"]),
                      "fits": [float(f) for f in cmp["fit_percent"]],
                      "true_fit": float(W.fit_percent(val["y"], val["y_clean"])),
                      "cost": float(res.cost), "converged": bool(res.converged),
                      "fit_s": seconds}))


def run(N: int, family: str, batch: str, orders: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        tm = Path(tmp) / "time"
        env = {**os.environ, "JTHERMO_CACHE_DIR": str(Path(tmp) / "cache")}
        cmd = ["/usr/bin/time", "-f", "%e %M", "-o", str(tm), sys.executable, __file__, "--child",
               str(N), family, batch, orders]
        p = subprocess.run(cmd, check=False, env=env, capture_output=True, text=True, cwd=ROOT)
        wall, rss = (float(x) for x in tm.read_text().split()[-2:])
    row = {"N": N, "family": family, "batch": batch, "wall_s": wall, "peak_rss_mb": rss / 1024,
           "load": os.getloadavg()[0], "exit": p.returncode}
    if p.returncode == 0:
        row.update(json.loads(p.stdout.strip().splitlines()[-1]))
    else:
        row["error"] = (p.stderr.strip().splitlines() or [""])[-1][:160]
    return row


def markdown(rows: list[dict], command: str) -> str:
    lines = ["# Polynomial PEM: output rows together (`vmap`) or one after another (`map`)", "",
             (f"`{command}`. Fresh process and empty compilation cache per row; wall and peak "
              "RSS by /usr/bin/time; fit = validation simulation fit (mean over outputs); "
              "Δ vs vmap = largest per-output fit difference to the `vmap` row; load = 1-minute "
              "load average after the row (2-core machine shared with other jobs: wall times "
              "are inflated by it)."), "",
             ("| N | family | orders | batch | fit % | true % | Δ vs vmap (points) | cost | "
              "converged | fit s | wall s | peak RSS MB | load |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    ref = {(r["N"], r["family"]): r for r in rows if r["batch"] == "vmap" and "fits" in r}
    for r in rows:
        if "fits" not in r:
            lines.append(f"| {r['N']} | {r['family']} | | {r['batch']} | error: {r.get('error')} "
                         f"| | | | | | {r['wall_s']:.1f} | {r['peak_rss_mb']:.0f} | {r['load']:.1f} |")
            continue
        base = ref.get((r["N"], r["family"]))
        delta = (max(abs(a - b) for a, b in zip(r["fits"], base["fits"]))
                 if base is not None and base.get("orders") == r["orders"] else None)
        o = " ".join(f"{k} {v}" for k, v in r["orders"].items())
        lines.append(f"| {r['N']} | {r['family']} | {o} | {r['batch']} | {r['fit']:.2f} | "
                     f"{r['true_fit']:.2f} | {'—' if delta is None else f'{delta:.1e}'} | "
                     f"{r['cost']:.6g} | {r['converged']} | {r['fit_s']:.1f} | {r['wall_s']:.1f} | "
                     f"{r['peak_rss_mb']:.0f} | {r['load']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        child(int(argv[1]), argv[2], argv[3], argv[4])
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=4)
    ap.add_argument("--orders", choices=("auto", "true"), default="auto")
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=FAMILIES)
    ap.add_argument("--batches", nargs="+", default=["vmap", "map"], choices=("vmap", "map"))
    args = ap.parse_args(argv)
    command = "python benchmarks/polynomial_batch.py " + " ".join(argv)
    out = RESULTS / f"identification_default_batch_n{args.n}_{args.orders}.md"
    rows = []
    for fam in args.families:
        for batch in args.batches:
            print(f"[batch] N={args.n} {fam} {batch} ...", file=sys.stderr, flush=True)
            rows.append(run(args.n, fam, batch, args.orders))
            out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
            out.write_text(markdown(rows, command))
    print(markdown(rows, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
