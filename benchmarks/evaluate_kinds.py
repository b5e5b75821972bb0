"""`tune.evaluate` of every classical design on the virtual printer's three held-out scenario
kinds (as `jthermo demo`'s scenario stage does), one process, cold or warm as its cache is:
per design the wall and CPU s of its `evaluate` call and the backend compiles it caused.

    JTHERMO_CACHE_DIR=$(mktemp -d) python benchmarks/evaluate_kinds.py --tag _s38 [--label L]

For another tree put it first on PYTHONPATH. Appends to `benchmarks/results/evaluate_kinds{tag}.md`.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jthermo.cli  # noqa: F401  (the command's runtime set-up: x64, cache)
from jax import monitoring

from jthermo.closedloop import REALISTIC_EFFECTS
from jthermo.control.design import FAMILIES, design
from jthermo.errors import JThermoError
from jthermo.printer import make_printer
from jthermo.tune import HELD_OUT, SCENARIOS, evaluate, printer_model

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tag", default="")
    ap.add_argument("--label", default="this checkout", help="names the tree (e.g. its commit)")
    args = ap.parse_args()
    compiles: list[float] = []
    monitoring.register_event_duration_secs_listener(
        lambda ev, dur, **_: compiles.append(dur) if ev.endswith("backend_compile_duration") else None)
    plant = make_printer(4, REALISTIC_EFFECTS, seed=0)
    base = printer_model(plant)
    rows, t_all, c_all = [], time.perf_counter(), time.process_time()
    for fam in FAMILIES:
        try:
            ctrl = design(fam, base)
        except JThermoError:
            continue
        k, t, c = len(compiles), time.perf_counter(), time.process_time()
        ev = evaluate(ctrl, plant, SCENARIOS, (HELD_OUT,), rollouts=4, duration=600.0)
        rows.append((fam, time.perf_counter() - t, time.process_time() - c, len(compiles) - k, ev["cost"]))
    load = Path("/proc/loadavg").read_text().split()[0]
    out = ROOT / "benchmarks" / "results" / f"evaluate_kinds{args.tag}.md"
    lines = [] if out.exists() else [
        "# `tune.evaluate` of every design on the three held-out kinds", "",
        "`python benchmarks/evaluate_kinds.py` (4-zone printer, 4 rollouts, 600 s, the demo's "
        "settings): per design its call's wall / CPU s and backend compiles; the cost to check "
        "that two trees agree.", ""]
    lines += [f"## {args.label}, load {load}: all designs "
              f"{time.perf_counter() - t_all:.1f} s wall, {time.process_time() - c_all:.1f} CPU s, "
              f"{sum(r[3] for r in rows)} compiles", "",
              "| design | wall s | CPU s | compiles | held-out cost |", "|---|---|---|---|---|"]
    lines += [f"| {f} | {w:.2f} | {c:.2f} | {n} | {cost:.10g} |" for f, w, c, n, cost in rows]
    with out.open("a") as fh:
        fh.write("\n".join(lines) + "\n\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
