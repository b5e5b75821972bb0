"""Memory maps a test process holds at its end, with and without the suite's per-module release
of compiled programs (`tests/conftest.py`, `_release_compiled_code`; `JTHERMO_TESTS_KEEP_COMPILED=1`
keeps them). Linux allows a process `vm.max_map_count` maps (65530 by default); every XLA CPU
executable keeps some for its code.

    .venv/bin/python benchmarks/memory_maps_tests.py [TEST FILES ...]

Runs the files in one pytest process (no xdist) per setting and writes
`benchmarks/results/memory_maps_tests.md`: maps and peak RSS at the end, wall and CPU seconds.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FILES = ["tests/diagnose/test_select.py", "tests/diagnose/test_fitting_joint.py",
         "tests/identify/test_pem.py", "tests/closedloop/test_engine_lean_metrics.py"]
CHILD = """
import json, resource, sys, pytest
rc = pytest.main(["-q", "-p", "no:xdist", "-p", "no:cacheprovider", "-m", "not slow", *sys.argv[1:]])
maps = sum(1 for _ in open("/proc/self/maps"))
print("RESULT " + json.dumps({"rc": int(rc), "maps": maps,
                               "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run(files, keep: bool) -> dict:
    env = dict(os.environ)
    env.pop("JTHERMO_TESTS_KEEP_COMPILED", None)
    if keep:
        env["JTHERMO_TESTS_KEEP_COMPILED"] = "1"
    t0, c0 = time.perf_counter(), os.times()
    out = subprocess.run([sys.executable, "-c", CHILD, *files], cwd=ROOT, env=env, capture_output=True,
                         text=True, check=False)
    c1 = os.times()
    line = next(x for x in out.stdout.splitlines() if x.startswith("RESULT "))
    return {**json.loads(line[7:]), "wall_s": time.perf_counter() - t0,
            "cpu_s": (c1.children_user + c1.children_system) - (c0.children_user + c0.children_system)}


def main(argv=None) -> int:
    files = list(argv if argv is not None else sys.argv[1:]) or FILES
    rows = {"kept (before)": run(files, True), "released per module (now)": run(files, False)}
    lines = ["# Memory maps of a test process", "",
             (f"`python benchmarks/memory_maps_tests.py {' '.join(files)}`: the files in one pytest "
             f"process; Linux's limit per process: {Path('/proc/sys/vm/max_map_count').read_text().strip()} "
             f"maps; load {os.getloadavg()[0]:.1f} at the end."), "",
             "| compiled programs | pytest exit | maps at the end | peak RSS MB | wall s | CPU s |", "|---|---|---|---|---|---|"]
    for name, r in rows.items():
        lines.append(f"| {name} | {r['rc']} | {r['maps']} | {r['peak_rss_mb']:.0f} | {r['wall_s']:.0f} | {r['cpu_s']:.0f} |")
    out = ROOT / "benchmarks" / "results" / "memory_maps_tests.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
