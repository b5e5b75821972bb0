"""The diagnosis's compiled programs with and without `runtime.quick_compile()` options.

The latency record of `benchmarks/latency.py` (one hour, 4 zones; 30 min of validation data) is
diagnosed until its first joint fit, keeping the arguments of the first call of each compiled
program (`fitting.fit_zones`: the candidates' per-zone fits, `sim_zones`, `fit_records`: the
validation's record estimation, `fit_joint`: the first joint fit). Each program is then lowered
and compiled with XLA's default options and with `runtime.quick_compile()` (XLA's older CPU
fusion emitters), no persistent cache, and run once (the joint fit with `--joint-iter`
iterations instead of its 25, to keep the run short). CPU s = user + system of this process
(the load-robust figure on the shared machine); the outputs of the two compiles are compared.

    python benchmarks/diagnose_compile_options.py [--joint-iter 4]

Writes `benchmarks/results/diagnose_compile_options.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from common import cpu_seconds  # noqa: E402

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
#: the latency benchmark's record (benchmarks/latency.py RECORD)
RECORD = ["--experiment", "prbs", "--zones", "4", "--effects",
          "lateral_conduction,radiative_loss,heater_lag"]



def _capture(est, val) -> dict:
    """First-call arguments of each compiled program of the diagnosis (until the joint stage)."""
    import jax
    import numpy as np

    from jthermo.data import load
    from jthermo.diagnose import select

    got: dict = {}

    class Stop(Exception):
        pass

    def wrap(name):
        orig = getattr(select, name)

        def cap(*a):
            got.setdefault(name, jax.tree_util.tree_map(lambda x: np.asarray(x) if hasattr(x, "shape") else x, a))
            if name == "fit_joint":
                raise Stop
            return orig(*a)
        setattr(select, name, cap)

    for nm in ("fit_zones", "sim_zones", "fit_records", "fit_joint"):
        wrap(nm)
    try:
        select.diagnose(load(est), load(val))
    except Stop:
        pass
    return got


def capture_latency_record() -> dict:
    """`_capture` on the latency record, written to a temporary directory (float64 on)."""
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
            p = str(Path(tmp) / name)
            subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", *RECORD, "--duration", dur,
                            "--seed", seed, "--out", p, "--quiet", "--no-cache"], check=True)
            paths.append(p)
        return _capture(*paths)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--joint-iter", type=int, default=4)
    args = ap.parse_args(argv)
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np

    from jthermo.diagnose import fitting as F
    from jthermo.runtime import quick_compile

    got = capture_latency_record()
    programs = {
        "fit_zones (candidates)": (F._fit_zones, ("lay", "n_iter", "n_active"), got["fit_zones"]),
        "sim_zones (candidates)": (F._sim_zones, ("lay",), got["sim_zones"]),
    }
    Th, on, rec0, mask, y, f_per, f_sh, lay, n_it = got["fit_records"]
    full = np.concatenate([np.zeros((Th.shape[0], Th[0].size), mask.dtype), mask], axis=1)
    programs["fit_records (validation)"] = (F._fit_joint, ("lay", "n_iter", "n_active"),
                                            (Th, on, rec0, full, y, np.ones(y.shape[0]), f_per, f_sh, lay, n_it,
                                             rec0.shape[1]))
    a = list(got["fit_joint"])
    a[9] = args.joint_iter
    programs[f"fit_joint (first joint fit, {args.joint_iter} iterations)"] = (
        F._fit_joint, ("lay", "n_iter", "n_active"), tuple(a))
    rows = []
    for label, (fn, static, fargs) in programs.items():
        import inspect
        names = list(inspect.signature(fn).parameters)
        dyn = [x for nm, x in zip(names, fargs) if nm not in static]
        outs = {}
        for opt_name, opts in (("default", None), ("quick_compile", quick_compile())):
            jax.clear_caches()
            c0 = cpu_seconds()
            lowered = jax.jit(fn, static_argnames=static, compiler_options=opts).lower(*fargs)
            c1 = cpu_seconds()
            comp = lowered.compile()
            c2 = cpu_seconds()
            out = jax.block_until_ready(comp(*dyn))
            c3 = cpu_seconds()
            outs[opt_name] = [np.asarray(v) for v in jax.tree_util.tree_leaves(out)]
            rows.append({"program": label, "options": opt_name, "trace_lower_cpu_s": c1 - c0,
                         "compile_cpu_s": c2 - c1, "run_cpu_s": c3 - c2, "load": os.getloadavg()[0]})
            print(rows[-1], flush=True)
        diff = max(float(np.max(np.abs(p - q)) / (np.max(np.abs(p)) + 1e-300))
                   for p, q in zip(outs["default"], outs["quick_compile"]))
        rows[-1]["max_rel_diff"] = rows[-2]["max_rel_diff"] = diff
    tot = {o: sum(r["compile_cpu_s"] for r in rows if r["options"] == o) for o in ("default", "quick_compile")}
    lines = ["# The diagnosis's compiled programs: default XLA options vs `runtime.quick_compile()`", "",
             ("`python benchmarks/diagnose_compile_options.py`: the latency record (1 h, 4 zones; 30 min "
              "validation), each program's first call of the diagnosis, lowered and compiled in this process "
              "(no persistent cache) with each option set, then run once. CPU s = user + system (load-robust; "
              "wall times on the shared 2-core machine are not). Largest output difference of the two compiles "
              "relative to the largest output entry."), "",
             "| program | options | trace + lower CPU s | compile CPU s | run CPU s | max rel. diff | load |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['program']} | {r['options']} | {r['trace_lower_cpu_s']:.2f} | {r['compile_cpu_s']:.2f} | "
              f"{r['run_cpu_s']:.2f} | {r['max_rel_diff']:.1e} | {r['load']:.1f} |" for r in rows]
    lines += ["", f"Compile CPU s of the four: default {tot['default']:.1f}, quick_compile {tot['quick_compile']:.1f}.",
              ""]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "diagnose_compile_options.md").write_text("\n".join(lines))
    (RESULTS / "diagnose_compile_options.json").write_text(json.dumps(rows, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
