"""Does `jthermo fit` from the shell gain from one BLAS thread?

The default-path records of `benchmarks/identification.py` (W1, absolute °C, 6000 + 3000
samples) fitted by `jthermo fit EST --model M --validation VAL --json OUT` in fresh processes,
alternately with one BLAS thread per core (`cores`: OpenBLAS's default when no variable is set;
since `jthermo.cli.one_blas_thread` the command sets 1 itself when none is, so `cores` sets
the variables to the core count) and one thread (`1`:
`OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1`), each
`--repeats` times, the persistent compilation cache warm (a first, untimed run fills it), so
that compilation does not drown the BLAS part. Wall, CPU (user + system) and peak RSS by
/usr/bin/time; the 1-minute load before each run (2 shared cores).

    python benchmarks/identification_blas.py --n 4 16 --families arx oe --repeats 2
    -> benchmarks/results/identification_blas.md (and .json)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def run_fit(folder: Path, fam: str, threads: str, cache: Path) -> dict:
    """One `jthermo fit` in a fresh process; `threads` "cores" or "1"."""
    env = {k: v for k, v in os.environ.items() if k not in BLAS_VARS}
    n = str(os.cpu_count()) if threads == "cores" else threads
    env.update({k: n for k in BLAS_VARS})
    env["JTHERMO_CACHE_DIR"] = str(cache)
    tm = folder / "time.txt"
    load = os.getloadavg()[0]
    cmd = ["/usr/bin/time", "-f", "%e %M %U %S", "-o", str(tm), str(ROOT / ".venv/bin/jthermo"),
           "fit", str(folder / "est.csv"), "--model", fam, "--validation", str(folder / "val.csv"),
           "--json", str(folder / "out.json")]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall, rss, user, system = (float(v) for v in tm.read_text().split()[-4:])
    fit = json.loads((folder / "out.json").read_text())["mean_fit_percent"] if p.returncode == 0 else None
    return {"wall_s": wall, "cpu_s": user + system, "peak_rss_mb": rss / 1024, "load": load,
            "exit": p.returncode, "fit": fit}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[4, 16])
    ap.add_argument("--families", nargs="+", default=["arx", "oe"])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/identification_blas.md")
    ap.add_argument("--merge", type=Path, help="rows of an earlier run (JSON) listed first")
    args = ap.parse_args(argv)
    import identification as B
    from jthermo.data import atomic_write_text

    rows = json.loads(args.merge.read_text()) if args.merge else []
    for N in args.n:
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            B.write_default_records(B.load_workloads(), N, 0, tmp)
            for fam in args.families:
                cache = tmp / f"cache_{fam}"
                run_fit(tmp, fam, "1", cache)                  # fills the cache, untimed
                for rep in range(args.repeats):
                    for threads in (("cores", "1") if rep % 2 == 0 else ("1", "cores")):
                        print(f"[blas] N={N} {fam} threads={threads} rep {rep}", file=sys.stderr,
                              flush=True)
                        rows.append({"N": N, "family": fam, "threads": threads, "rep": rep,
                                     **run_fit(tmp, fam, threads, cache)})
                        atomic_write_text(args.out.with_suffix(".json"), json.dumps(rows, indent=1))
    lines = ["# `jthermo fit` from the shell: one BLAS thread per core vs 1", "",
             __doc__.split("\n\n")[1].replace("\n", " "), "",
             f"Command: `python benchmarks/identification_blas.py {' '.join(argv or sys.argv[1:])}`; "
             f"{os.cpu_count()} CPU cores.", "",
             "| N | family | BLAS threads | rep | wall s | CPU s | peak RSS MB | fit % | load before |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        fit = "—" if r["fit"] is None else f"{r['fit']:.4f}"
        lines.append(f"| {r['N']} | {r['family']} | {r['threads']} | {r['rep']} | {r['wall_s']:.2f} | "
                     f"{r['cpu_s']:.2f} | {r['peak_rss_mb']:.0f} | {fit} | {r['load']:.1f} |")
    atomic_write_text(args.out, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
