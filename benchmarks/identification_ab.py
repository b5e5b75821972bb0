"""Before/after of a change on the default path: `jthermo fit` with automatic orders, cold from
the shell, for two source trees run alternately on the same records and the same load.

"before" is the package at git revision `--rev` (extracted by `git archive` into a temporary
folder and put first on PYTHONPATH), "after" the working tree; both run the same `.venv`. For
each N and family the two alternate `--repeats` times, each in a fresh process with an empty
compilation cache (JTHERMO_CACHE_DIR), on W1 default-path records
(`identification.write_default_records`: absolute °C, 6000 + 3000 samples; `--seed`,
`--noise-std`, `--noise-pole` as in `identification.py --default-path`). Wall, CPU
(user + system) and peak RSS by /usr/bin/time; the CPU seconds are the load-robust figure.

    python benchmarks/identification_ab.py --rev 8b26d97 --n 4 9 --families ss [--repeats 2]
    -> benchmarks/results/identification_ab_<rev>_<families>_n<N...>.md (and .json)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import identification as B  # noqa: E402


def extract(rev: str, folder: Path) -> Path:
    """The `jthermo` package at `rev`, extracted under `folder`; returns the PYTHONPATH entry
    (checked: a process started there with it imports that copy, not the editable install)."""
    archive = subprocess.run(["git", "archive", rev, "jthermo"], cwd=ROOT, check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    where = subprocess.run([str(ROOT / ".venv/bin/python"), "-c",
                            "import jthermo; print(jthermo.__file__)"], cwd=folder, text=True,
                           env={**os.environ, "PYTHONPATH": str(folder)}, capture_output=True,
                           check=True).stdout.strip()
    if not where.startswith(str(folder)):
        raise RuntimeError(f"the 'before' tree is not the one imported: {where}")
    return folder


def markdown(rows: list[dict], command: str) -> str:
    lines = ["# Default path before / after, alternating runs", "",
             f"`{command}`. before = the package at `{rows[0]['rev'] if rows else ''}`, after = "
             "the working tree; each row a fresh process with an empty compilation cache; "
             "load = mean 1-minute load average over the run (2 shared cores: wall grows with "
             "it, CPU much less). gap = validation fit − the true model's.", "",
             "| N | family | run | tree | orders | fit % | gap | converged | wall s | CPU s | peak MB | load |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        o = " ".join(f"{k} {v}" for k, v in (r.get("orders") or {}).items())
        lines.append(f"| {r['N']} | {r['family']} | {r['run']} | {r['tree']} | {o} | "
                     f"{B._fmt(r.get('fit'), 3)} | {B._fmt(r.get('gap'), 3)} | "
                     f"{r.get('converged', r.get('error', '—'))} | {r['wall_s']:.1f} | "
                     f"{r['cpu_s']:.1f} | {r['peak_rss_mb']:.0f} | {r['load']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", required=True, help="git revision of the 'before' package")
    ap.add_argument("--n", type=int, nargs="+", default=[4])
    ap.add_argument("--families", nargs="+", default=["ss"])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise-std", type=float, default=None)
    ap.add_argument("--noise-pole", type=float, default=None)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    from jthermo.data import atomic_write_text

    command = "python benchmarks/identification_ab.py " + " ".join(argv or sys.argv[1:])
    variant = "".join(f"_{k}{v:g}" for k, v in (("seed", args.seed or None),
                      ("noise", args.noise_std), ("pole", args.noise_pole)) if v is not None)
    out = args.out or (ROOT / "benchmarks" / "results" / (
        f"identification_ab_{args.rev}_{'_'.join(args.families)}_n{'_'.join(map(str, args.n))}"
        f"{variant}.md"))
    W = B.with_noise(B.load_workloads(), args.noise_std, args.noise_pole)
    rows = []
    with tempfile.TemporaryDirectory(prefix="jthermo-ab-") as tmp:
        tmp = Path(tmp)
        old = extract(args.rev, tmp)
        for N in args.n:
            _, val = B.write_default_records(W, N, args.seed, tmp)
            truth = W.fit_percent(val["y"], val["y_clean"])
            for fam in args.families:
                for run in range(args.repeats):
                    for name, tree in (("before", old), ("after", None)):
                        print(f"[ab] N={N} {fam} run {run} {name}", file=sys.stderr, flush=True)
                        r = B.shell_fit(tmp, fam, f"{fam}{N}{run}{name}", pythonpath=tree)
                        r.update(N=N, family=fam, run=run, tree=name, rev=args.rev,
                                 load=(r["load_before"] + r["load"]) / 2,
                                 gap=r["fit"] - truth if "fit" in r else None)
                        rows.append(r)
                        atomic_write_text(out, markdown(rows, command))
                        atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1))
    print(markdown(rows, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
