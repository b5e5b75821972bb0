"""The diagnosis's fits before and after, on the latency record, same answers.

"before" is the package at `--rev` (`git archive` into a temporary folder, first on PYTHONPATH);
"after" is the same tree with `--overlay` files taken from the working tree (by default the two
files this change touches: `identify/lm.py`, `diagnose/fitting.py`), so that other concurrent
edits enter neither. Each tree diagnoses the latency record of `benchmarks/latency.py` (one
hour, 4 zones; 30 min validation) in a fresh process with an empty compilation cache, twice:
pass 1 compiles (cold), pass 2 reuses the compiled programs (warm, in-process). Every call of
the compiled fits (`fit_zones`, `sim_zones`, `fit_records`, `fit_joint`) is timed, blocked
until ready; CPU s = user + system of the process (the load-robust figure: 2 shared cores),
the 1-minute load beside. The trees are run alternately, `--repeats` times each.

Answers: the finding, the augmented model's validation fit and every fit's cost (`fit_joint`,
`fit_records`: the cost of each model; `fit_zones`: of each zone problem) are compared between
the trees.

    python benchmarks/diagnose_overlay_ab.py [--rev 8b3d005] [--repeats 1]

Writes `benchmarks/results/diagnose_overlay_ab.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import cpu_seconds  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
#: the latency benchmark's record (benchmarks/latency.py RECORD)
RECORD = ["--experiment", "prbs", "--zones", "4", "--effects",
          "lateral_conduction,radiative_loss,heater_lag"]
PROGRAMS = ("fit_zones", "sim_zones", "fit_records", "fit_joint")
OVERLAY = ("jthermo/identify/lm.py", "jthermo/diagnose/fitting.py")



def _child(est: str, val: str, out: str) -> None:
    """Diagnose the record twice in this process; time every compiled call; write JSON."""
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import jthermo
    from jthermo.data import load
    from jthermo.diagnose import select

    calls: list = []

    def wrap(name):
        orig = getattr(select, name)

        def timed(*a):
            w0, c0, ld = time.perf_counter(), cpu_seconds(), os.getloadavg()[0]
            got = jax.block_until_ready(orig(*a))
            calls.append({"program": name, "wall_s": time.perf_counter() - w0, "cpu_s": cpu_seconds() - c0, "load": ld,
                          "cost": [float(v) for v in np.ravel(got[-1] if name != "fit_zones" else got[1])]
                          if name != "sim_zones" else []})
            return got
        setattr(select, name, timed)

    for nm in PROGRAMS:
        wrap(nm)
    passes = []
    for p in (1, 2):
        calls.clear()
        w0, c0, ld = time.perf_counter(), cpu_seconds(), os.getloadavg()[0]
        res = select.diagnose(load(est), load(val))
        passes.append({"pass": p, "wall_s": time.perf_counter() - w0, "cpu_s": cpu_seconds() - c0,
                       "load": (ld + os.getloadavg()[0]) / 2, "calls": list(calls),
                       "verdict": res.get("verdict"), "mechanisms": [f["mechanism"] for f in res.get("findings", [])],
                       "fit": res.get("augmented", {}).get("mean_fit_percent")})
    Path(out).write_text(json.dumps({"package": jthermo.__file__, "passes": passes}))


def _tree(rev: str, folder: Path, overlay: tuple) -> Path:
    """The package at `rev` under `folder`, with `overlay` files copied from the working tree."""
    archive = subprocess.run(["git", "archive", rev, "jthermo"], cwd=ROOT, check=True, capture_output=True).stdout
    folder.mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    for f in overlay:
        shutil.copy(ROOT / f, folder / f)
    return folder


def _run(tree: Path, tmp: Path, tag: str) -> dict:
    out = tmp / f"{tag}.json"
    env = {**os.environ, "PYTHONPATH": str(tree), "JTHERMO_CACHE_DIR": str(tmp / f"cache-{tag}"),
           "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", str(tmp / "est.csv"),
                    str(tmp / "val.csv"), str(out)], cwd=tree, env=env, check=True)
    got = json.loads(out.read_text())
    if not got["package"].startswith(str(tree)):
        raise RuntimeError(f"{tag}: imported {got['package']}, not the tree under test")
    return got


def _sum(calls, prog, key):
    return sum(c[key] for c in calls if c["program"] == prog)


def markdown(runs: list, rev: str, overlay: tuple, command: str) -> str:
    lines = ["# `jthermo diagnose`'s fits before / after", "",
             f"`{command}`: before = the package at `{rev}`, after = the same with "
             + ", ".join(f"`{f}`" for f in overlay) + " from the working tree. The latency record "
             "(1 h, 4 zones; 30 min validation) diagnosed twice per fresh process (empty compilation "
             "cache): pass 1 compiles, pass 2 runs warm (in-process). CPU s = user + system (all "
             "threads; load-robust), wall s inflated by the load (2 shared cores).", "",
             "| tree | run | pass | diagnose CPU s | wall s | load | " + " | ".join(f"{p} CPU s" for p in PROGRAMS)
             + " |", "|---|---|---|---|---|---|" + "---|" * len(PROGRAMS)]
    for r in runs:
        for p in r["passes"]:
            lines.append(f"| {r['tree']} | {r['run']} | {p['pass']} | {p['cpu_s']:.1f} | {p['wall_s']:.1f} | "
                         f"{p['load']:.1f} | " + " | ".join(f"{_sum(p['calls'], g, 'cpu_s'):.2f}" for g in PROGRAMS)
                         + " |")
    lines += ["", "## Answers (pass 2 of the first run of each tree)", ""]
    b = next(r for r in runs if r["tree"] == "before")["passes"][1]
    a = next(r for r in runs if r["tree"] == "after")["passes"][1]
    lines += [f"- before: {b['verdict']}, {', '.join(b['mechanisms'])}; augmented fit {b['fit']!r} %",
              f"- after: {a['verdict']}, {', '.join(a['mechanisms'])}; augmented fit {a['fit']!r} %", "",
              "| call | program | models | largest relative cost difference |", "|---|---|---|---|"]
    same = len(a["calls"]) == len(b["calls"])
    for k, (cb, ca) in enumerate(zip(b["calls"], a["calls"])):
        if cb["program"] != ca["program"]:
            same = False
            break
        if cb["cost"]:
            d = max(abs(x - y) / abs(x) for x, y in zip(cb["cost"], ca["cost"]))
            lines.append(f"| {k + 1} | {cb['program']} | {len(cb['cost'])} | {d:.1e} |")
    if not same:
        lines.append("\nThe two trees made different calls: the costs above stop where they part.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", default="8b3d005")
    ap.add_argument("--overlay", nargs="*", default=list(OVERLAY))
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--child", nargs=3, metavar=("EST", "VAL", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        _child(*args.child)
        return
    with tempfile.TemporaryDirectory(prefix="jthermo-diaglat-") as d:
        tmp = Path(d)
        for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
            subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", *RECORD, "--duration", dur, "--seed",
                            seed, "--out", str(tmp / name), "--quiet", "--no-cache"], check=True, cwd=ROOT)
        trees = {"before": _tree(args.rev, tmp / "before", ()),
                 "after": _tree(args.rev, tmp / "after", tuple(args.overlay))}
        runs = []
        for k in range(args.repeats):
            for tag, tree in trees.items():
                got = _run(tree, tmp, f"{tag}{k}")
                runs.append({"tree": tag, "run": k + 1, "passes": got["passes"]})
                p = got["passes"]
                print(f"{tag} run {k + 1}: pass 1 {p[0]['cpu_s']:.1f} CPU s, pass 2 {p[1]['cpu_s']:.1f} CPU s "
                      f"(load {p[1]['load']:.1f}); {p[1]['mechanisms']} {p[1]['fit']}", flush=True)
    command = "python benchmarks/diagnose_overlay_ab.py" + (f" --rev {args.rev}" if args.rev != "8b3d005" else "") \
        + (f" --repeats {args.repeats}" if args.repeats != 1 else "")
    RESULTS.mkdir(exist_ok=True)
    stem = RESULTS / "diagnose_overlay_ab"
    stem.with_suffix(".json").write_text(json.dumps({"rev": args.rev, "overlay": args.overlay, "runs": runs},
                                                    indent=1))
    text = markdown(runs, args.rev, tuple(args.overlay), command)
    stem.with_suffix(".md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
