"""What the end of a `jthermo simulate` process costs: the interpreter's teardown after `main()`
returned (normal exit) against `cli.common.exit_now` (flush, atexit handlers, `os._exit`).

Each row is a fresh process with a warm cache (filled by a first, untimed process): it runs
`jthermo.cli.main([...simulate...])`, records its own CPU seconds when `main` returns, then
exits one way or the other; the parent takes the child's total CPU seconds (user + system)
from `getrusage`. Teardown = total - at main's return. Interleaved, `--repeats` each.

    python benchmarks/simulate_teardown.py [--repeats 3] [--out -]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from common import finish, load

HERE = Path(__file__).resolve().parent
ARGV = ["simulate", "--scenario", "tracking", "--controller", "pi", "--zones", "16",
        "--rollouts", "256", "--duration", "3600", "--quiet"]

CHILD = r"""
import json, os, sys, time
from jthermo.cli import main
from jthermo.cli.common import exit_now
rc = main(json.loads(sys.argv[1]))
t = time.process_time()
with open(sys.argv[3], "w") as f:
    f.write(json.dumps({"cpu_at_return": t}))
exit_now(rc) if sys.argv[2] == "exit_now" else sys.exit(rc)
"""


def _child(mode: str, env: dict, note: Path) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-c", CHILD, json.dumps(ARGV), mode, str(note)], env=env,
                   check=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    at_return = json.loads(note.read_text())["cpu_at_return"]
    return {"mode": mode, "cpu_total": total, "cpu_at_return": at_return,
            "teardown_cpu": total - at_return, "load": load()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_teardown.md"))
    args = ap.parse_args()
    load0 = load()
    rows = []
    with tempfile.TemporaryDirectory(prefix="jthermo-teardown-") as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
        env.pop("JTHERMO_NO_CACHE", None)
        env.update(JTHERMO_CACHE_DIR=tmp, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
        note = Path(tmp) / "note.json"
        _child("sys.exit", env, note)   # fills the cache
        for _ in range(args.repeats):
            for mode in ("sys.exit", "exit_now"):
                rows.append(_child(mode, env, note))
                print(rows[-1], flush=True)
    lines = ["# The end of a warm `jthermo simulate` process: interpreter teardown", "",
             (f"`python benchmarks/simulate_teardown.py --repeats {args.repeats}`: command "
              f"`jthermo {' '.join(ARGV)}` run in-process by `cli.main` in a fresh child with a "
              "warm cache, then ended by `sys.exit` (the interpreter's teardown) or by "
              "`cli.common.exit_now`; CPU s (user + system of the child, all threads). "
              "Interleaved; 1-minute load before each child in the table (2 shared cores)."), "",
             "| exit | CPU s at main's return | CPU s total | teardown CPU s | load |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['mode']} | {r['cpu_at_return']:.2f} | {r['cpu_total']:.2f} | "
                     f"{r['teardown_cpu']:.3f} | {r['load']} |")
    for mode in ("sys.exit", "exit_now"):
        med = statistics.median(r["teardown_cpu"] for r in rows if r["mode"] == mode)
        tot = statistics.median(r["cpu_total"] for r in rows if r["mode"] == mode)
        lines.append(f"\nMedian {mode}: teardown {med:.3f} CPU s, process {tot:.2f} CPU s.")
    finish(lines, load0, args.out)


if __name__ == "__main__":
    main()
