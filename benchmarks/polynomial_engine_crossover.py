"""Where is each PEM engine faster? The measurement behind `fit_polynomial(engine="auto")`.

For each family (ARMAX, OE, BJ), zone count N (N outputs, N inputs), record length T and
engine (`jax`: the compiled PEM, `numpy`: `pem_numpy`, `auto`: the rule under test), one fresh
process with an empty compilation cache (JTHERMO_CACHE_DIR) runs `fit(data, family)` with
automatic orders, the default path of `jthermo fit`, on W1 records in absolute °C
(`identification.write_default_records`' recipe, T estimation + 3000 validation samples):
the first call (`cold`: what `jthermo fit` pays, compilation included) and a second call on the
same data (`warm`: a process that fits the same shape again), wall and CPU (user + system)
seconds of each call, the whole process's wall / CPU / peak RSS by /usr/bin/time (imports and
the validation simulation included: the shell figure), the chosen orders, the parameters per
output row `p` and the validation fit. CPU seconds are the load-robust figure; wall seconds
show what the compiled engine's second core buys.

    python benchmarks/polynomial_engine_crossover.py --n 1 2 4 9 16 --t 6000 \
        [--engines jax numpy] [--families armax oe bj]
    -> benchmarks/results/polynomial_engine_crossover<tag>.md (and .json)
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

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import identification as B  # noqa: E402

VAL_T = 3000


def child(family: str, folder: Path, engine: str) -> dict:
    """In a fresh process: `fit` twice (cold, warm) with `engine`, the validation fit %."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    from jthermo import runtime
    from jthermo.data import load
    from jthermo.identify.fit import fit
    from jthermo.identify.polynomial import n_params_per_output

    runtime.enable_cache(os.environ["JTHERMO_CACHE_DIR"])
    est, val = load(folder / "est.csv"), load(folder / "val.csv")
    row = {}
    for key in ("cold", "warm"):
        t0, c0 = time.perf_counter(), time.process_time()
        res = fit(est, family, engine=engine)
        row[f"{key}_s"], row[f"{key}_cpu"] = time.perf_counter() - t0, time.process_time() - c0
    from jthermo.validate import compare

    row["fit"] = float(compare(res.model, val)["mean_fit_percent"])
    row["orders"] = dict(res.orders)
    row["p"] = n_params_per_output(family, res.orders, est.n_inputs)
    row["converged"] = bool(res.converged)
    row["engine_used"] = (res.extra or {}).get("engine", engine)
    row["n_rows"] = int(np.asarray(est.y).shape[1])
    return row


def run(family: str, folder: Path, engine: str, tag: str, cores: int | None = None) -> dict:
    """`child` under /usr/bin/time in a fresh process with an empty cache folder; `cores`: the
    process pinned to the first `cores` CPUs (`taskset`), as on a machine with that many."""
    tm = folder / f"{tag}.time"
    env = {**os.environ, "JTHERMO_CACHE_DIR": str(folder / f"cache_{tag}")}
    pin = ["taskset", "-c", f"0-{cores - 1}"] if cores else []
    cmd = [*pin, "/usr/bin/time", "-f", "%e %M %U %S", "-o", str(tm), sys.executable, __file__,
           "--child", family, str(folder), engine]
    load0 = os.getloadavg()[0]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=ROOT, check=False)
    wall, rss, user, system = (float(v) for v in tm.read_text().split()[-4:])
    row = {"process_wall_s": wall, "process_cpu_s": user + system, "peak_rss_mb": rss / 1024,
           "load": (load0 + os.getloadavg()[0]) / 2}
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode or not lines:
        row["error"] = (p.stderr.strip().splitlines() or [f"exit {p.returncode}"])[-1][:160]
    else:
        row.update(json.loads(lines[-1]))
    return row


def records(W, N: int, T: int, seed: int, folder: Path) -> dict:
    """W1 records (T estimation, `VAL_T` validation samples, ambient 25 °C) in `folder`."""
    from jthermo.data import from_arrays, save_csv

    est, val = W.make_dataset(N, T, seed, 1), W.make_dataset(N, VAL_T, seed, 2)
    for name, d in (("est", est), ("val", val)):
        save_csv(from_arrays(d["u"], 25.0 + d["y"]), folder / f"{name}.csv")
    return {"true_fit": W.fit_percent(val["y"], val["y_clean"])}


def markdown(rows: list[dict], command: str) -> str:
    f = B._fmt
    lines = ["# PEM engines: where each is faster (fresh process, automatic orders)", "",
             (f"`{command}`; {os.cpu_count()} CPU cores (shared with other jobs: load = mean "
              "1-minute load average over the row). Each row one fresh process with an empty "
              "compilation cache: `fit(est, family, engine=...)` twice (cold = first call, "
              "compilation included; warm = second call, same shapes); process = the whole "
              "process by /usr/bin/time (imports, CSV load, both fits, validation). p = "
              "parameters per output row; w = N·T·p (the NumPy engine's work per LM step, "
              "up to a constant). gap = validation fit − the true model's."), "",
             ("| family | N | T | cores | engine | orders | p | w = N·T·p | cold s (CPU) | warm s (CPU) "
              "| process s (CPU) | peak MB | fit % | gap | load | note |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        o = " ".join(f"{k} {v}" for k, v in (r.get("orders") or {}).items())
        w = r["N"] * r["T"] * r["p"] if "p" in r else None
        eng = r["engine"] + (f" → {r['engine_used']}" if r.get("engine_used") not in
                             (None, r["engine"]) else "")
        lines.append(
            f"| {r['family']} | {r['N']} | {r['T']} | {r.get('cores') or os.cpu_count()} | {eng} | {o} | {r.get('p', '—')} | "
            f"{f(w, 0) if w else '—'} | {f(r.get('cold_s'), 2)} ({f(r.get('cold_cpu'), 2)}) | "
            f"{f(r.get('warm_s'), 2)} ({f(r.get('warm_cpu'), 2)}) | "
            f"{f(r['process_wall_s'], 1)} ({f(r['process_cpu_s'], 1)}) | "
            f"{f(r['peak_rss_mb'], 0)} | {f(r.get('fit'), 3)} | {f(r.get('gap'), 3)} | "
            f"{f(r['load'], 1)} | {r.get('error', '' if r.get('converged', True) else 'not converged')} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 2, 4, 9, 16])
    ap.add_argument("--t", type=int, nargs="+", default=[6000], help="estimation samples")
    ap.add_argument("--families", nargs="+", default=["armax", "oe", "bj"],
                    choices=("armax", "oe", "bj"))
    ap.add_argument("--engines", nargs="+", default=["jax", "numpy"],
                    choices=("jax", "numpy", "auto"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cores", type=int, default=None,
                    help="pin each fit process to this many CPUs (taskset; default: all)")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(child(args.child[0], Path(args.child[1]), args.child[2])), flush=True)
        return 0
    from jthermo.data import atomic_write_text

    command = "python benchmarks/polynomial_engine_crossover.py " + " ".join(argv or sys.argv[1:])
    out = ROOT / "benchmarks" / "results" / "polynomial_engine_crossover.md"
    W = B.load_workloads()
    rows = []
    for N in args.n:
        for T in args.t:
            with tempfile.TemporaryDirectory(prefix="jthermo-engine-") as tmp:
                tmp = Path(tmp)
                truth = records(W, N, T, args.seed, tmp)["true_fit"]
                for fam in args.families:
                    for eng in args.engines:
                        print(f"[crossover] N={N} T={T} {fam} {eng}", file=sys.stderr, flush=True)
                        r = {"family": fam, "N": N, "T": T, "engine": eng, "seed": args.seed,
                             "cores": args.cores, **run(fam, tmp, eng, f"{fam}_{eng}", args.cores)}
                        if "fit" in r:
                            r["gap"] = r["fit"] - truth
                        rows.append(r)
                        atomic_write_text(out, markdown(rows, command))
                        atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1))
    print(markdown(rows, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
