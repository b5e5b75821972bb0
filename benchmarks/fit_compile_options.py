"""Compile options of the PEM solve (`identify.pem`'s `_minimize_jit`, `minimize_many_jit`):
XLA's defaults against `runtime.quick_compile()` (XLA's older CPU fusion emitters) and
`runtime.simulate_compile()` (those at LLVM -O1), on `jthermo demo`'s fits (4 zones, 3600 s
PRBS record, the demo's orders and starts, each family in turn) — each mode in a fresh
process with an empty compilation cache (cold: compile + run), then each fit again in the
same process (run alone); the fitted costs and validation fits of every mode are compared.

    python benchmarks/fit_compile_options.py   # writes benchmarks/results/fit_compile_options.md
    python benchmarks/fit_compile_options.py --modes default,quick --repeats 2   # interleaved
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from simulate_common import cold_child

ROOT = Path(__file__).resolve().parent.parent
MODES = ("default", "quick", "simulate")


def child(mode: str) -> list:
    import equinox as eqx
    import jax

    jax.config.update("jax_enable_x64", True)
    from jthermo import demo, runtime
    from jthermo.identify import pem
    from jthermo.identify.fit import fit
    from jthermo.printer import generate, make_printer
    from jthermo.validate import compare

    runtime.enable_cache()
    runtime.unroll_threefry()
    opts = {"default": None, "quick": runtime.quick_compile(), "simulate": runtime.simulate_compile()}[mode]
    pem._minimize_jit = eqx.filter_jit(pem._minimize_impl, compiler_options=opts)
    pem.minimize_many_jit = eqx.filter_jit(pem.minimize_many_jit.__wrapped__, compiler_options=opts)
    p = make_printer(4, demo.ID_EFFECTS, seed=0)
    est = generate(p, "prbs", 3600.0, seed=0)
    val = generate(p, "prbs", 1800.0, seed=1)
    rows = []
    for fam, orders in demo.FAMILY_ORDERS.items():
        times = []
        for _ in range(2):
            t, c = time.perf_counter(), time.process_time()
            res = fit(est, fam, orders, seed=0, n_starts=demo.SETTINGS["full"]["n_starts"])
            times.append((time.perf_counter() - t, time.process_time() - c))
        fitp = compare(res.model, val)
        rows.append([fam, times[0][0], times[0][1], times[1][0], times[1][1],
                     float(res.cost) if res.cost is not None else float("nan"),
                     float(fitp.get("mean_fit_percent", float("nan")))])
    return rows


def main() -> None:
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        print(json.dumps(child(sys.argv[2])))
        return
    modes = sys.argv[sys.argv.index("--modes") + 1].split(",") if "--modes" in sys.argv else MODES
    repeats = int(sys.argv[sys.argv.index("--repeats") + 1]) if "--repeats" in sys.argv else 1
    runs = []
    for mode in [m for _ in range(repeats) for m in modes]:
        runs.append((mode, *cold_child(__file__, mode)))
    lines = ["# PEM solve: compile options (issue 13)", "",
             f"`python benchmarks/fit_compile_options.py {' '.join(sys.argv[1:])}`: `jthermo demo`'s fits, each mode in a fresh "
             "process with an empty compilation cache; first = compile + run, again = the same fit "
             "repeated in the process. 2 shared CPUs, 1-minute load before each process.", "",
             "| mode | family | first wall s | first CPU s | again wall s | again CPU s | cost | validation fit % | load |",
             "|---|---|---|---|---|---|---|---|---|"]
    for mode, load, rows in runs:
        lines += [f"| {mode} | {r[0]} | {r[1]:.2f} | {r[2]:.2f} | {r[3]:.2f} | {r[4]:.2f} | {r[5]:.10g} | "
                  f"{r[6]:.4f} | {load} |" for r in rows]
        lines.append(f"| {mode} | **all** | {sum(r[1] for r in rows):.2f} | {sum(r[2] for r in rows):.2f} | "
                     f"{sum(r[3] for r in rows):.2f} | {sum(r[4] for r in rows):.2f} | | | |")
    text = "\n".join(lines) + "\n"
    out = ROOT / "benchmarks/results" / f"fit_compile_options{'_' + '_'.join(modes) if modes != MODES else ''}.md"
    out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
