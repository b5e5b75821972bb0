"""`jthermo demo` from two source trees, cold (empty compilation cache) then warm (a second run
on the cache the first filled), interleaved, each in its own process from the tree's directory
(`python -m jthermo.cli demo`), wall and CPU s (user + sys of the child) and the demo's own
stage times (its JSON report):

    git archive REV | (mkdir -p BASE && tar -x -C BASE)
    python benchmarks/demo_time_ab.py --base BASE --base-label REV [--out FILE]

`--base`/`--base-label` may repeat (several trees against this checkout); `--repeats K` runs the
whole interleaved round (every tree cold, then every tree warm) K times, each round on fresh
caches.
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

ROOT = Path(__file__).resolve().parent.parent


def run(tree: Path, cache: str, tmp: Path) -> dict:
    js = tmp / "demo.json"
    env = dict(os.environ, PYTHONPATH=str(tree), JTHERMO_CACHE_DIR=cache)
    load = Path("/proc/loadavg").read_text().split()[0]
    t = time.perf_counter()
    p = subprocess.Popen([sys.executable, "-m", "jthermo.cli", "demo", "--quiet", "--runs-dir",
                          str(tmp / "runs"), "--json", str(js)], cwd=str(tree), env=env,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    rep = json.loads(js.read_text()) if js.exists() else {}
    stages = {r.get("stage", "?"): r.get("seconds") for r in rep.get("stages", [])}
    return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "rc": os.waitstatus_to_exitcode(status),
            "load": load, "stages": stages}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, action="append")
    ap.add_argument("--base-label", action="append")
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/demo_time_ab.md"))
    args = ap.parse_args()
    labels = args.base_label or [f"base{i}" for i in range(len(args.base))]
    trees = {lab: Path(b).resolve() for lab, b in zip(labels, args.base)}
    trees["this checkout"] = ROOT
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.repeats):
            caches = {k: tempfile.mkdtemp(dir=tmp) for k in trees}
            for phase in ("cold", "warm"):
                for name, tree in trees.items():
                    work = Path(tempfile.mkdtemp(dir=tmp))
                    rows.append((name, phase, run(tree, caches[name], work)))
    lines = ["# `jthermo demo`: two trees, cold and warm", "",
             f"`python benchmarks/demo_time_ab.py --repeats {args.repeats} "
             + " ".join(f"--base BASE --base-label {lab}" for lab in labels) + "`: each run "
             "a fresh process from the tree's directory; cold = an empty compilation cache, warm = "
             "the second run on the cache the first filled; 2 shared CPUs, 1-minute load before each run.", "",
             "| tree | run | wall s | CPU s | exit | load | stages (s) |", "|---|---|---|---|---|---|---|"]
    for name, phase, r in rows:
        def short(k):
            return "scenarios" if k.startswith("the three") else k.split(" ")[0]
        st = ", ".join(f"{short(k)} {v:.1f}" for k, v in r["stages"].items() if v is not None)
        lines.append(f"| {name} | {phase} | {r['wall']:.1f} | {r['cpu']:.1f} | {r['rc']} | {r['load']} | {st} |")
    text = "\n".join(lines) + "\n"
    Path(args.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
