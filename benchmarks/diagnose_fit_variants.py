"""A/B of the diagnosis's compiled fits on the latency record's own problems: the same calls,
compiled another way, timed one after another (CPU s, best of `--reps`), outputs compared.

The latency record of `benchmarks/diagnose_profile.py` is diagnosed once in this process with
the arguments of every `fit_zones` and `fit_joint` call kept; then each call is rerun as

- `as is`: the program the diagnosis runs (`runtime.quick_compile()` options, its `n_active`);
- `default options`: XLA's default CPU options;
- `n_active = own`: (joint calls) the static Jacobian width cut to the call's largest number of
  free parameters (rounded up to 4) instead of `joint.joint_active`'s bound;

and the variants' costs and parameters are compared with `as is` (largest relative difference).

    python benchmarks/diagnose_fit_variants.py [--reps 2]

Writes `benchmarks/results/diagnose_fit_variants.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
sys.path.insert(0, str(HERE))
from common import cpu_seconds, load1
from diagnose_profile import write_record


def timed(fn, args, reps):
    """(first call CPU s (compile + run), best later call CPU s, outputs)."""
    c0 = cpu_seconds()
    out = jax.block_until_ready(fn(*args))
    first = cpu_seconds() - c0
    best = math.inf
    for _ in range(reps):
        c0 = cpu_seconds()
        jax.block_until_ready(fn(*args))
        best = min(best, cpu_seconds() - c0)
    return first, best, out


def rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b) / (np.abs(b) + 1e-12)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=2)
    args = ap.parse_args()
    import jax.numpy as jnp

    from jthermo.data import load
    from jthermo.diagnose import fitting, joint, select, to_json
    from jthermo.runtime import quick_compile

    load0 = load1()
    with tempfile.TemporaryDirectory(prefix="jthermo-variants-") as d:
        tmp = Path(d)
        est, val = (load(f) for f in write_record(tmp))
    calls = []

    def keep(name, fn):
        def wrapper(*a):
            calls.append((name, a))
            return fn(*a)
        return wrapper

    select.fit_zones = keep("fit_zones", select.fit_zones)
    joint.fit_joint = keep("fit_joint", joint.fit_joint)
    js = to_json(select.diagnose(est, val))
    print(js["augmented"]["mechanisms"], js["augmented"]["mean_fit_percent"], flush=True)
    quick = quick_compile()
    rows = []
    for ci, (name, a) in enumerate(calls):
        if name == "fit_zones":
            fn, static = fitting._fit_zones, ("lay", "n_iter", "n_active")
            budget = a[8] if len(a) > 8 else np.full(a[0].shape[0], a[6])     # each problem's iterations
            call = tuple(a[:8]) + (jnp.asarray(budget, jnp.int32),)
            variants = {"as is": (quick, call), "default options": (None, call)}
        else:
            src = fitting.first_copies(*a[:4], a[6])
            if len(set(src.tolist())) == 1:
                continue
            budget = np.where(src == np.arange(src.size), a[9], 0).astype(np.int32)
            call = tuple(a) + (jnp.asarray(budget),)
            fn, static = fitting._fit_joint, ("lay", "n_iter", "n_active")
            own = 4 * math.ceil(int(np.max(np.sum(np.asarray(a[3]) > 0, axis=1))) / 4)
            variants = {"as is": (quick, call), "default options": (None, call),
                        f"n_active = own ({own})": (quick, call[:10] + (own,) + call[11:])}
        ref = None
        for label, (opts, cargs) in variants.items():
            f = jax.jit(fn, static_argnames=static, compiler_options=opts)
            first, best, out = timed(lambda *x: f(*x), cargs, args.reps)
            if name != "fit_zones":           # copies take their first's fit (`fitting.fit_joint`)
                out = tuple(np.asarray(x)[src] for x in out)
            cost = out[1] if name == "fit_zones" else out[3]
            theta = out[0]
            if ref is None:
                ref = (cost, theta)
            row = {"call": ci, "fit": name, "variant": label, "first_cpu_s": first, "run_cpu_s": best,
                   "cost_rel_diff": rel(cost, ref[0]), "theta_rel_diff": rel(theta, ref[1]),
                   "cost_sum": float(np.sum(np.asarray(cost)))}
            rows.append(row)
            print(row, flush=True)
    out = {"rows": rows, "load_before": load0, "load_after": load1()}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "diagnose_fit_variants.json").write_text(json.dumps(out, indent=1) + "\n")
    lines = ["# Diagnosis fits compiled other ways", "",
             f"`python benchmarks/diagnose_fit_variants.py"
             f" --reps {args.reps}`: the latency record's calls, load {load0:.2f} → {out['load_after']:.2f}; "
             "first call = trace + compile + run, run = best later call (CPU s); differences relative to `as is`.", "",
             "| call | fit | variant | first CPU s | run CPU s | cost rel. diff | θ rel. diff |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['call']} | {r['fit']} | {r['variant']} | {r['first_cpu_s']:.2f} | {r['run_cpu_s']:.2f} | "
                     f"{r['cost_rel_diff']:.1e} | {r['theta_rel_diff']:.1e} |")
    (RESULTS / "diagnose_fit_variants.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
