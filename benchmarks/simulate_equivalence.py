"""`jthermo simulate` of two trees on a grid of controllers, scenarios and zone counts: the
same JSON report (metrics, cost, set points) to a relative tolerance, and the wall time of
each command (cold: each tree gets its own fresh compilation cache, so the first command of a
program compiles it).

    python benchmarks/simulate_equivalence.py --base /tmp/base   # a `git archive` of BASE

writes `benchmarks/results/simulate_equivalence.md`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

#: (controller, scenario, zones): every family at tracking, every scenario with pi, and
#: zone counts 1 and 16
GRID = ([(c, "tracking", 4) for c in ("pi", "lqg", "imc", "feedforward", "pi_decoupled")]
        + [("pi", s, 4) for s in ("powder", "print", "preheat", "ensemble")]
        + [("pi", "tracking", 1), ("lqg", "print", 1), ("pi", "tracking", 16),
           ("lqg", "print", 16)])


def _run(tree: Path, cache: Path, argv: list[str], out: Path) -> tuple[dict, float]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env.pop("JTHERMO_NO_CACHE", None)
    env.update(JTHERMO_CACHE_DIR=str(cache), PYTHONPATH=str(tree))
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "jthermo.cli", *argv, "--quiet", "--json", str(out)],
                       env=env, capture_output=True, text=True, cwd=str(tree))
    wall = time.perf_counter() - t0
    if r.returncode:
        return {"error": r.stderr.strip().splitlines()[-1:]}, wall
    return json.loads(out.read_text()), wall


def _differences(a: dict, b: dict, rtol: float) -> list[str]:
    bad = []
    for k in sorted(set(a.get("metrics", {})) | set(b.get("metrics", {}))):
        x, y = a.get("metrics", {}).get(k), b.get("metrics", {}).get(k)
        if x is None or y is None or not math.isclose(x, y, rel_tol=rtol, abs_tol=1e-12):
            bad.append(f"{k} {x} vs {y}")
    for k in ("cost", "setpoints", "duration", "zones", "rollouts"):
        if k in a and json.dumps(a[k]) != json.dumps(b.get(k)) and not (
                k == "cost" and math.isclose(a[k], b.get(k, math.nan), rel_tol=rtol)):
            bad.append(f"{k} differs")
    return bad


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="the other tree (e.g. a git archive)")
    ap.add_argument("--base-label", default="base")
    ap.add_argument("--rollouts", type=int, default=8)
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--rtol", type=float, default=1e-9)
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_equivalence.md"))
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="jthermo-equiv-") as d:
        tmp = Path(d)
        for i, (ctrl, kind, zones) in enumerate(GRID):
            argv = ["simulate", "--scenario", kind, "--controller", ctrl, "--zones", str(zones),
                    "--rollouts", str(args.rollouts), "--duration", f"{args.duration:g}"]
            load = os.getloadavg()[0]
            a, wa = _run(Path(args.base), tmp / "cache-base", argv, tmp / f"a{i}.json")
            b, wb = _run(ROOT, tmp / "cache-this", argv, tmp / f"b{i}.json")
            bad = (["error: " + str(a.get("error") or b.get("error"))]
                   if "error" in a or "error" in b else _differences(a, b, args.rtol))
            rows.append((ctrl, kind, zones, wa, wb, load, a.get("metrics", {}).get("mse"),
                         b.get("metrics", {}).get("mse"), bad))
            print(rows[-1], flush=True)
    lines = ["# `jthermo simulate`: this checkout against an earlier tree", "",
             (f"`python benchmarks/simulate_equivalence.py --base {args.base_label}` "
              f"(--rollouts {args.rollouts} --duration {args.duration:g}): the same command "
              f"with each tree, each tree with its own fresh compilation cache (programs shared "
              f"by several rows are compiled by the first); every metric, the cost and the set "
              f"points compared to a relative tolerance of {args.rtol:g}. Wall s of each "
              f"command; 1-minute load before the pair."), "",
             f"| controller | scenario | zones | {args.base_label} s | this s | load | "
             f"mse {args.base_label} | mse this | differences |",
             "|---|---|---|---|---|---|---|---|---|"]
    for c, k, z, wa, wb, load, ma, mb, bad in rows:
        lines.append(f"| {c} | {k} | {z} | {wa:.1f} | {wb:.1f} | {load:.2f} | {ma!r} | {mb!r} | "
                     f"{'; '.join(bad) if bad else 'none'} |")
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
