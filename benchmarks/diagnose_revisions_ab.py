"""`jthermo diagnose` before / after on snapshots, interleaved, same answers.

Two revisions are extracted (`git archive REV jthermo`) into temporary folders and put first on
`PYTHONPATH`; each diagnoses the latency record (`benchmarks/diagnose_profile.py`'s child: 1 h,
4 zones, 30 min validation, in-process, every compiled fit timed) in a fresh process, in the
order: every tree cold, then every tree warm (cold: an empty compilation cache of its
own; warm: a second process on the cache its cold run filled), `--repeats` times. CPU s = user
+ system of the process (all threads; the load-robust figure on 2 shared cores), the 1-minute
load beside. The answers are compared between the trees: verdict, findings, augmented model,
every tried combination's mean validation fit, the augmented model's parameters.

    python benchmarks/diagnose_revisions_ab.py --base 5647e9c --this HEAD

Writes `benchmarks/results/diagnose_revisions_ab.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
sys.path.insert(0, str(HERE))
from diagnose_profile import RECORD, _subprocess  # noqa: E402


def _tree(rev: str, folder: Path) -> Path:
    archive = subprocess.run(["git", "archive", rev, "jthermo"], cwd=ROOT, check=True,
                             capture_output=True).stdout
    folder.mkdir(parents=True)
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def _joint(run: dict) -> float:
    return sum(r["cpu_s"] for k, r in run["rows"].items() if k.startswith("joint call") and k.endswith("total"))


def _max_rel(a, b) -> float:
    a, b = np.asarray(a, float).ravel(), np.asarray(b, float).ravel()
    if a.shape != b.shape:
        return float("inf")
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-12))) if a.size else 0.0


def _flat_params(p) -> list:
    if isinstance(p, dict):
        return [v for k in sorted(p) for v in _flat_params(p[k])]
    if isinstance(p, (list, tuple)):
        return [v for x in p for v in _flat_params(x)]
    return [float(p)] if isinstance(p, (int, float)) else []


def _strs(p) -> list:
    """The non-numeric leaves (names, rivals, flags) of a JSON tree, in order."""
    if isinstance(p, dict):
        return [(k, v) for k in sorted(p) for v in _strs(p[k])]
    if isinstance(p, (list, tuple)):
        return [v for x in p for v in _strs(x)]
    return [] if isinstance(p, (int, float)) and not isinstance(p, bool) else [p]


def compare(a: dict, b: dict) -> dict:
    same = all(a[k] == b[k] for k in ("verdict", "findings", "augmented"))
    same = same and [c["mechanisms"] for c in a["combinations"]] == [c["mechanisms"] for c in b["combinations"]]
    same = same and _strs(a.get("findings_detail", [])) == _strs(b.get("findings_detail", []))
    same = same and [c["accepted"] for c in a["combinations"]] == [c["accepted"] for c in b["combinations"]]
    return {"same_names": bool(same),
            "augmented_fit_rel": _max_rel([a["augmented_fit"]], [b["augmented_fit"]]),
            "combination_fits_rel": _max_rel([c["mean_fit_percent"] for c in a["combinations"]],
                                             [c["mean_fit_percent"] for c in b["combinations"]]),
            "parameters_rel": _max_rel(_flat_params(a["parameters"]), _flat_params(b["parameters"])),
            "findings_rel": _max_rel(_flat_params(a.get("findings_detail", [])),
                                     _flat_params(b.get("findings_detail", [])))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True)
    ap.add_argument("--this", default="HEAD", help="revision(s) to compare with --base, comma-separated")
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    revs = {}
    for label in [args.base] + args.this.split(","):
        revs[label] = subprocess.run(["git", "rev-parse", "--short", label], cwd=ROOT, check=True,
                                     capture_output=True, text=True).stdout.strip()
    runs = []
    with tempfile.TemporaryDirectory(prefix="jthermo-diag27-") as d:
        tmp = Path(d)
        trees = {lab: _tree(rev, tmp / f"tree-{i}") for i, (lab, rev) in enumerate(revs.items())}
        env = dict(os.environ, JTHERMO_NO_CACHE="1")
        for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
            subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", *RECORD, "--duration", dur,
                            "--seed", seed, "--out", str(tmp / name), "--quiet"], check=True, env=env)
        old = os.environ.get("PYTHONPATH")
        try:
            for rep in range(args.repeats):
                for phase in ("cold", "warm"):
                    for i, (lab, tree) in enumerate(trees.items()):
                        os.environ["PYTHONPATH"] = str(tree)
                        row = _subprocess(phase, tmp / "est.csv", tmp / "val.csv", tmp / f"cache-{rep}-{i}",
                                          tmp / f"{rep}-{i}-{phase}.json", None)
                        row.update(tree=lab, rev=revs[lab], repeat=rep)
                        runs.append(row)
        finally:
            if old is None:
                os.environ.pop("PYTHONPATH", None)
            else:
                os.environ["PYTHONPATH"] = old
    base = args.base
    lines = ["# `jthermo diagnose` before / after on snapshots", "",
             f"`python benchmarks/diagnose_revisions_ab.py --base {args.base} --this {args.this} --repeats "
             f"{args.repeats}`: "
             + ", ".join(f"`{lab}` = `{rev}`" for lab, rev in revs.items()) + " (`git archive` snapshots). The latency record (1 h, 4 zones; 30 min validation) "
             "diagnosed in a fresh process per run (`diagnose_profile.py`'s child), interleaved: every "
             "tree cold, then every tree warm (on its own cold run's cache). CPU s = user + system (all threads), the load-robust figure; "
             "wall s follows the load (2 shared cores).", "",
             "| repeat | phase | tree | wall s | CPU s | compile s (trace / lowering / backend) | joint stage CPU s "
             "| load | answer |", "|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        ev = r.get("compile_by_event", {})
        lines.append(f"| {r['repeat']} | {r['phase']} | {r['tree']} ({r['rev']}) | {r['total_wall_s']:.1f} | "
                     f"{r['total_cpu_s']:.1f} | {r['compile_s']:.1f} ({ev.get('jaxpr_trace_duration', 0):.1f} / "
                     f"{ev.get('jaxpr_to_mlir_module_duration', 0):.1f} / {ev.get('backend_compile_duration', 0):.1f})"
                     f" | {_joint(r):.1f} | {r['load_before']:.2f} | {' + '.join(r['augmented'])} "
                     f"{r['augmented_fit']:.6f} % |")
    lines += ["", "Medians:", "", "| phase | tree | wall s | CPU s | compile s | joint stage CPU s |",
              "|---|---|---|---|---|---|"]
    for phase in ("cold", "warm"):
        for lab in revs:
            rs = [r for r in runs if r["phase"] == phase and r["tree"] == lab]
            med = lambda f: statistics.median(f(r) for r in rs)  # noqa: E731
            lines.append(f"| {phase} | {lab} | {med(lambda r: r['total_wall_s']):.1f} | "
                         f"{med(lambda r: r['total_cpu_s']):.1f} | {med(lambda r: r['compile_s']):.1f} | "
                         f"{med(_joint):.1f} |")
    lines += ["", "Answers, each tree against base (same repeat and phase):", "",
              "| repeat | phase | tree | same names | augmented fit rel. diff | combinations' fits rel. diff | "
              "parameters rel. diff | findings' numbers rel. diff |", "|---|---|---|---|---|---|---|---|"]
    cmp = []
    for r in runs:
        if r["tree"] == base:
            continue
        b = next(x for x in runs if x["tree"] == base and x["repeat"] == r["repeat"] and x["phase"] == r["phase"])
        c = compare(r, b)
        cmp.append({"tree": r["tree"], **c})
        lines.append(f"| {r['repeat']} | {r['phase']} | {r['tree']} | {c['same_names']} | {c['augmented_fit_rel']:.1e} | "
                     f"{c['combination_fits_rel']:.1e} | {c['parameters_rel']:.1e} | {c['findings_rel']:.1e} |")
    RESULTS.mkdir(exist_ok=True)
    stem = RESULTS / "diagnose_revisions_ab"
    stem.with_suffix(".json").write_text(json.dumps({"runs": runs, "compare": cmp}, indent=1, default=float) + "\n")
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
