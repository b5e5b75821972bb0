"""What compiled bytecode saves the first `jthermo` command: importing the CLI's modules from
the package with fresh `__pycache__` (as `make` leaves it: `compileall` at install) against the
same sources without bytecode (what an editable install's first process compiles).

Each run is a fresh process importing the command modules (`cli.control`, `closedloop`,
`control.design`, `diagnose`, `tune`); the two arms alternate, CPU s = user + sys of the child.

    python benchmarks/bytecode_import.py --pairs 7
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
IMPORTS = "import jthermo.cli.control, jthermo.closedloop, jthermo.control.design, jthermo.diagnose, jthermo.tune"


def run(src: Path) -> float:
    """CPU s of one fresh process importing the command modules from `src` (no bytecode written)."""
    env = dict(os.environ, PYTHONPATH=str(src), PYTHONDONTWRITEBYTECODE="1")
    p = subprocess.Popen([sys.executable, "-c", IMPORTS], env=env, cwd=src)
    _, status, ru = os.wait4(p.pid, 0)
    if status != 0:
        raise SystemExit(f"import failed in {src}")
    return ru.ru_utime + ru.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=7)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="jthermo-bytecode-") as d:
        fresh, bare = Path(d) / "fresh", Path(d) / "bare"
        for dst in (fresh, bare):
            shutil.copytree(ROOT / "jthermo", dst / "jthermo", ignore=shutil.ignore_patterns("__pycache__"))
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(fresh / "jthermo")], check=True)
        times: dict[str, list[float]] = {"bytecode": [], "sources only": []}
        for _ in range(args.pairs):
            times["bytecode"].append(run(fresh))
            times["sources only"].append(run(bare))
    load = os.getloadavg()[0]
    print(f"importing the command modules, {args.pairs} alternating pairs, 1-min load {load:.2f} at the end:")
    for k, v in times.items():
        print(f"  {k:13s} median {statistics.median(v):.2f} CPU s (min {min(v):.2f}, max {max(v):.2f})")


if __name__ == "__main__":
    main()
