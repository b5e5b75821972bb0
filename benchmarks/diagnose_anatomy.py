"""Where the diagnosis's fitting time goes, per problem: distinct models per joint call, LM
iterations until each fit stops, and the cost of one iteration's parts.

The latency record of `benchmarks/diagnose_profile.py` (one hour, 4 zones; 30 min validation)
is diagnosed once in this process with every `fit_zones` / `fit_joint` call's arguments kept.
Then, for each call:

- the distinct models (`fitting.fit_joint` copies a slot that repeats an earlier one),
- each distinct problem refitted alone with its history (`masked_lm` as the call runs it), the
  iterations until it stopped (the early-stop rule replayed on the history) and Jacobians formed
  (iterations whose step was accepted, plus the first),
- for the joint calls: the CPU time of one Jacobian (`jax.linearize` + the vmapped tangents) at
  the call's static `n_active` and at the problem's own number of free parameters, of one
  residual (a simulation), and of the whole fit.

    python benchmarks/diagnose_anatomy.py

Writes `benchmarks/results/diagnose_anatomy.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
sys.path.insert(0, str(HERE))
from common import cpu_seconds, load1
from diagnose_profile import write_record


def iterations(hist, c) -> int:
    """Iterations `masked_lm(..., rtol=RTOL)` ran, replayed from its history `hist` (after the
    stop: the final cost repeated): the first k at which its loop condition fails."""
    from jthermo.diagnose.fitting import RTOL
    from jthermo.identify.lm import STALL

    hist = np.asarray(hist)
    for k in range(len(hist) + 1):
        if k > STALL:
            back = hist[k - 1 - STALL]
            cur = hist[k - 1]
            if back - cur <= RTOL * abs(back):
                return k
    return len(hist)


def accepted(hist, c0) -> int:
    """Accepted steps in a history (the cost fell)."""
    h = np.concatenate([[c0], np.asarray(hist)])
    return int(np.sum(h[1:] < h[:-1]))


def _timeit(fn, *args, reps=3) -> float:
    jax.block_until_ready(fn(*args))
    best = np.inf
    for _ in range(reps):
        c0 = cpu_seconds()
        jax.block_until_ready(fn(*args))
        best = min(best, cpu_seconds() - c0)
    return best


def _joint_residual(Th0, onj, f, lay, y, weight):
    from jthermo.diagnose.mechanisms import simulate_full

    nP = Th0.size

    def res(v):
        Th, r = v[:nP].reshape(Th0.shape), v[nP:]
        return (weight[:, None] * (y - simulate_full(Th, onj, f, lay, r))).reshape(-1)
    return res


def _zone_residual(on_b, z, lay):
    from jthermo.diagnose.mechanisms import simulate_zone

    return lambda th: z["y"] - simulate_zone(th, on_b, z, lay)


def _per(a, j):
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x[j]), a)


def problems(name, a):
    """(jitted fit with history, jitted residual, Jacobian builder, args of problem j)."""
    from jthermo.diagnose.fitting import RTOL
    from jthermo.identify.lm import masked_lm

    if name == "fit_joint":
        Theta0, on, rec0, mask, y, weight, f_per, f_shared, lay, n_iter, n_active = a
        y, weight = jnp.asarray(y), jnp.asarray(weight)

        def make(p):
            Th0, onj, r0, m, fp = p
            res = _joint_residual(Th0, onj, {**f_shared, **fp}, lay, y, weight)
            return res, jnp.concatenate([Th0.reshape(-1), r0]), m
        pick = lambda j: _per((Theta0, on, rec0, mask, f_per), j)
    else:
        theta0, mask, on, per, shared, lay, n_iter, n_active = a

        def make(p):
            t0, m, o, pz = p
            return _zone_residual(o, {**shared, **pz}, lay), t0, m
        pick = lambda j: _per((theta0, mask, on, per), j)

    def fit(p):
        res, v0, m = make(p)
        th, c, hist = masked_lm(res, v0, m, n_iter, n_active, rtol=RTOL)
        return c, hist, jnp.mean(res(v0) ** 2)

    def residual(p):
        res, v0, _ = make(p)
        return res(v0)

    def jac(na):
        def lin(p):
            res, v0, m = make(p)
            idx = jnp.nonzero(m > 0, size=na, fill_value=0)[0]
            tang = jax.nn.one_hot(idx, v0.shape[0], dtype=v0.dtype)
            r, jvp = jax.linearize(res, v0)
            return r, jax.vmap(jvp, out_axes=1)(tang)
        return jax.jit(lin)
    return jax.jit(fit), jax.jit(residual), jac, pick, n_iter, n_active


def fit_history(fit, p):
    c0 = cpu_seconds()
    c, hist, cost0 = jax.block_until_ready(fit(p))
    first = cpu_seconds() - c0
    c0 = cpu_seconds()
    jax.block_until_ready(fit(p))
    run = cpu_seconds() - c0
    cost0 = float(cost0)
    return {"iterations": iterations(hist, c), "accepted": accepted(hist, cost0), "cost0": cost0,
            "cost": float(c), "first_call_cpu_s": first, "run_cpu_s": run}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zone-sample", type=int, default=12, help="per-zone problems refitted per call")
    args = ap.parse_args()
    from jthermo.data import load
    from jthermo.diagnose import candidates, fitting, joint, select, to_json, validation

    load0 = load1()
    with tempfile.TemporaryDirectory(prefix="jthermo-anatomy-") as d:
        tmp = Path(d)
        est, val = (load(f) for f in write_record(tmp))
    calls = []

    def keep(name, fn):
        def wrapper(*a):
            out = fn(*a)
            calls.append((name, jax.tree_util.tree_map(lambda x: np.asarray(x) if hasattr(x, "shape") else x, a)))
            return out
        return wrapper

    candidates.fit_zones = keep("fit_zones", candidates.fit_zones)
    validation.fit_records = keep("fit_records", validation.fit_records)
    joint.fit_joint = keep("fit_joint", joint.fit_joint)
    c0, t0 = cpu_seconds(), time.perf_counter()
    js = to_json(select.diagnose(est, val))
    diag = {"cpu_s": cpu_seconds() - c0, "wall_s": time.perf_counter() - t0,
            "findings": [f["mechanism"] for f in js["findings"]],
            "augmented": js["augmented"]["mechanisms"], "fit": js["augmented"]["mean_fit_percent"]}
    print(diag, flush=True)
    rows = []
    jac_cache = {}
    for ci, (name, a) in enumerate(calls):
        if name == "fit_records":
            rows.append({"call": ci, "name": name, "slots": int(a[0].shape[0])})
            continue
        fit, residual, jac, pick, n_iter, n_active = problems(name, a)
        if name == "fit_joint":
            src = fitting.first_copies(*a[:4], a[6])
            todo = sorted(set(src.tolist()))
            row = {"call": ci, "name": name, "slots": len(src), "distinct": len(todo),
                   "n_iter": n_iter, "n_active": n_active, "models": []}
        else:
            B = a[0].shape[0]
            todo = np.unique(np.linspace(0, B - 1, min(args.zone_sample, B)).round().astype(int)).tolist()
            row = {"call": ci, "name": name, "problems": B, "n_iter": n_iter, "n_active": n_active, "models": []}
        for j in todo:
            p = pick(j)
            fh = fit_history(fit, p)
            fh["free"] = int(np.sum(np.asarray(p[3] if name == "fit_joint" else p[1]) > 0))
            if name == "fit_joint" and j == todo[-1]:
                fh["residual_cpu_s"] = _timeit(residual, p)
                for key, na in (("jacobian_n_active_cpu_s", n_active), ("jacobian_own_cpu_s", max(fh["free"], 1))):
                    if (key, na, ci) not in jac_cache:
                        jac_cache[(key, na, ci)] = _timeit(jac(na), p)
                    fh[key] = jac_cache[(key, na, ci)]
            row["models"].append({"slot" if name == "fit_joint" else "problem": j, **fh})
            print(ci, name, j, fh, flush=True)
        rows.append(row)
    out = {"diagnosis": diag, "calls": rows, "load_before": load0, "load_after": load1()}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "diagnose_anatomy.json").write_text(json.dumps(out, indent=1, default=float) + "\n")
    lines = ["# Diagnosis anatomy", "",
             "`python benchmarks/diagnose_anatomy.py`: the latency "
             "record's diagnosis (findings " + ", ".join(diag["findings"]) + f", augmented fit {diag['fit']:.2f} %), "
             f"load {load0:.2f} → {out['load_after']:.2f}. Each problem refitted alone (jitted, second call "
             "timed: run CPU s); iterations until the early stop, accepted steps; Jacobian CPU s at the call's "
             "static n_active and at the problem's own free-parameter count.", "",
             "| call | fit | slots / distinct | problem | free / n_active | iterations (accepted) | cost0 → cost | "
             "run CPU s | residual CPU s | Jacobian CPU s (n_active / own) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for mdl in r.get("models", []):
            lines.append(f"| {r['call']} | {r['name']} | {r.get('slots', r.get('problems'))} / {r.get('distinct', '')} | "
                         f"{mdl.get('slot', mdl.get('problem'))} | {mdl['free']} / {r['n_active']} | "
                         f"{mdl['iterations']} ({mdl['accepted']}) of {r['n_iter']} | {mdl['cost0']:.4g} → {mdl['cost']:.6g} | "
                         f"{mdl['run_cpu_s']:.3f} | {mdl.get('residual_cpu_s', float('nan')):.4f} | "
                         f"{mdl.get('jacobian_n_active_cpu_s', float('nan')):.4f} / "
                         f"{mdl.get('jacobian_own_cpu_s', float('nan')):.4f} |")
    (RESULTS / "diagnose_anatomy.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
