"""How far the per-zone candidate fits (`fitting.fit_zones`, `select.N_ITER`) run, and what
stopping them earlier would change: every problem (zone x candidate x start) of a diagnosis
refitted with the same masked Levenberg–Marquardt for a fixed `--ref` iterations (no early
stop: the iterates are those of the early-stopping loop, `identify.lm.masked_lm`), its cost
trajectory kept; the stopping rule (fall over `lm.STALL` iterations <= rtol x cost, at most the
call's `n_iter`) is then replayed on it for each rtol, and each cap cut at 30/60/100.

Per problem: iterations used (production rule, rtol `fitting.RTOL`), whether it hit the cap,
relative gap (cost - cost at `--ref`) / cost at `--ref` at 30/60/100 iterations and at each
rtol's stop. Per candidate (each zone its best start, as `mechanisms.best_of_starts`): its
estimation sum of squares under each variant against the reference, as the likelihood-ratio
shift m log(SSE / SSE_ref) (m = T n residuals), and the iterations each variant spends.

    python benchmarks/diagnose_zone_convergence.py --record latency [--ref 300]
    python benchmarks/diagnose_zone_convergence.py --record dev:12:8 --max-zones 9

`dev:S:I`: case I of `experiments/diagnose_heldout_hard.py --seed-set S` (a development set:
the records this study looks into are not held out any more). Writes
`benchmarks/results/diagnose_zone_convergence.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from common import cpu_seconds  # noqa: E402

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "experiments"))

from jthermo import data
from jthermo.data import atomic_write_text
from jthermo.diagnose import candidates, fitting, select
from jthermo.diagnose import mechanisms as M
from jthermo.identify.lm import STALL, masked_lm

RTOLS = (1e-10, 1e-9, 1e-8, 1e-7, 1e-6)
CUTS = (30, 60, 100)



def load_record(spec: str, max_zones: int):
    if spec == "latency":
        from diagnose_profile import write_record

        tmp = Path(tempfile.mkdtemp())
        e, v = write_record(tmp)
        return data.load(e), data.load(v)
    _, s, i = spec.split(":")
    import diagnose_heldout_hard as H

    c = H.draw_case(int(i), H.KINDS[int(i) % len(H.KINDS)], max_zones, int(s))
    return H.make_record(c)


def zone_residual(theta, on, z, lay):
    """A per-zone problem's residual, as `fitting.fit_zones` fits it: the zone's record less
    its simulation (`mechanisms.simulate_zone`)."""
    return z["y"] - M.simulate_zone(theta, on, z, lay)


def _fixed(theta0, mask, on, per, shared, lay, n_iter, n_active):
    def one(a):
        t, m, o, p = a
        z = {**shared, **p}
        return masked_lm(lambda th: zone_residual(th, o, z, lay), t, m, n_iter, n_active)

    return jax.lax.map(one, (theta0, mask, on, per))


_fixed_jit = jax.jit(_fixed, static_argnames=("lay", "n_iter", "n_active"))


def stop_at(hist, c0, rtol, cap):
    """The early-stopping loop's iteration count and cost, replayed on a fixed-loop history."""
    h = np.concatenate([[c0], hist])          # h[k] = cost after k iterations
    for k in range(1, cap + 1):
        if k > STALL and h[k - 1 - STALL] - h[k] <= rtol * abs(h[k - 1 - STALL]):
            return k, h[k], True
    return cap, h[cap], False


def labels(cands, n_problems, n, call):
    if call == 0:
        names = list(cands)
        if "heat_accumulation" in cands:
            names += [f"heat_accumulation@tau{int(t)}" for t in M.BODY_START_TAUS]
        if "radiative_loss" in cands:
            names += [f"radiative_loss@rho{s}" for s in M.RAD_SHARE_STARTS]
    else:
        names = ["heat_accumulation@from_drift"]
    assert len(names) * n == n_problems, (names, n_problems, n)
    return [(nm, i) for nm in names for i in range(n)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--record", default="latency")
    ap.add_argument("--max-zones", type=int, default=9)
    ap.add_argument("--ref", type=int, default=300, help="fixed iterations of the reference run (per n_iter 200)")
    args = ap.parse_args(argv)
    est, val = load_record(args.record, args.max_zones)
    calls = []
    orig = candidates.fit_zones

    def spy(*a):
        t0, c0 = time.perf_counter(), cpu_seconds()
        out = orig(*a)
        jax.block_until_ready(out)
        calls.append({"args": a[:7], "cost": np.asarray(out[1]), "wall_s": time.perf_counter() - t0,
                      "cpu_s": cpu_seconds() - c0})
        return out

    candidates.fit_zones = spy
    t0, c0 = time.perf_counter(), cpu_seconds()
    res = select.to_json(select.diagnose(est, val))
    diag = {"wall_s": time.perf_counter() - t0, "cpu_s": cpu_seconds() - c0,
            "findings": [(f["mechanism"], round(f["confidence"], 4)) for f in res["findings"]],
            "candidates": {r["mechanism"]: round(r["estimation_lr"], 2) for r in res["candidates"]}}
    candidates.fit_zones = orig
    n, T = est.n_outputs, est.n_samples
    cands = [m for m in M.MECHANISMS if n >= 2 or m not in select.NEEDS_NEIGHBOURS]
    problems = []
    for ci, call in enumerate(calls):
        theta0, mask, on, per, shared, lay, n_iter = call["args"]
        n_active = 4 * int(np.ceil(np.asarray(mask).sum(axis=1).max() / 4))
        ref = args.ref * n_iter // 200
        c1 = cpu_seconds()
        _, _, hist = _fixed_jit(theta0, mask, on, per, shared, lay, ref, n_active)
        hist = np.asarray(hist)
        call["ref_cpu_s"] = cpu_seconds() - c1
        c0s = np.asarray(jax.vmap(lambda t, o, p, sh=shared, ly=lay:
                                  jnp.mean(zone_residual(t, o, {**sh, **p}, ly) ** 2))(theta0, on, per))
        for b, (nm, zone) in enumerate(labels(cands, theta0.shape[0], n, ci)):
            h, cref = hist[b], hist[b, -1]
            k, _, stopped = stop_at(h, c0s[b], fitting.RTOL, n_iter)
            row = {"call": ci, "n_iter": n_iter, "label": nm, "zone": zone,
                   "free": int(np.sum(np.asarray(mask[b]) > 0)), "c_ref": float(cref),
                   "prod_cost": float(call["cost"][b]), "iters": k, "hit_cap": not stopped,
                   "still_falling_at_ref": bool(h[-1 - STALL] - h[-1] > fitting.RTOL * abs(h[-1 - STALL])),
                   "gap_cut": {str(q): float((h[min(q, n_iter) - 1] - cref) / cref) for q in CUTS + (n_iter,)},
                   "rtol": {}, "hist": [float(x) for x in h[::5]]}
            for r in RTOLS:
                kr, cr, _ = stop_at(h, c0s[b], r, n_iter)
                row["rtol"][f"{r:g}"] = {"iters": kr, "gap": float((cr - cref) / cref), "cost": float(cr)}
            problems.append(row)
    # per candidate: each zone its best start, as best_of_starts (the drift start joins the body)
    variants = {f"rtol {r:g}": ("rtol", f"{r:g}") for r in RTOLS}
    variants.update({f"cap {q}": ("cut", q) for q in CUTS})
    variants["no extra starts"] = ("nostarts", None)
    variants["no drift start"] = ("nodrift", None)

    def cost_of(p, how):
        if how[0] == "rtol":
            return p["rtol"][how[1]]["cost"], p["rtol"][how[1]]["iters"]
        if how[0] == "cut":
            q = min(how[1], p["n_iter"])
            return p["c_ref"] * (1 + p["gap_cut"][str(how[1])]), min(q, p["iters"])
        return p["rtol"][f"{fitting.RTOL:g}"]["cost"], p["rtol"][f"{fitting.RTOL:g}"]["iters"]

    cand_rows = []
    ref_sse = {}
    for m in cands:
        sse_ref = 0.0
        for z in range(n):
            ps = [p for p in problems if p["label"].split("@")[0] == m and p["zone"] == z]
            sse_ref += T * min(p["c_ref"] for p in ps)
        ref_sse[m] = sse_ref
    for vname, how in variants.items():
        tot_it = 0
        row = {"variant": vname, "lr_shift": {}}
        for p in problems:
            if how[0] == "nostarts" and "@" in p["label"]:
                continue
            if how[0] == "nodrift" and p["label"].endswith("from_drift"):
                continue
            tot_it += cost_of(p, how)[1]
        for m in cands:
            sse = 0.0
            for z in range(n):
                ps = [p for p in problems if p["label"].split("@")[0] == m and p["zone"] == z
                      and not (how[0] == "nostarts" and "@" in p["label"])
                      and not (how[0] == "nodrift" and p["label"].endswith("from_drift"))]
                sse += T * min(cost_of(p, how)[0] for p in ps)
            row["lr_shift"][m] = float(n * T * np.log(sse / ref_sse[m]))
        row["iterations"] = tot_it
        cand_rows.append(row)
    out = {"record": args.record, "n": n, "T": T, "diagnosis": diag,
           "calls": [{k: v for k, v in c.items() if k not in ("args", "cost")} for c in calls],
           "problems": problems, "variants": cand_rows}
    L = [f"# Per-zone candidate fits: iterations and convergence ({args.record})", "",
         f"`python benchmarks/diagnose_zone_convergence.py --record {args.record} --max-zones {args.max_zones} "
         f"--ref {args.ref}`: N = {n}, T = {T}; diagnosis "
         f"{diag['wall_s']:.1f} s wall, {diag['cpu_s']:.1f} CPU s, load {os.getloadavg()[0]:.1f}; findings "
         f"{diag['findings']}. Fit_zones calls: "
         + "; ".join(f"n_iter {c['args'][6]}, {c['args'][0].shape[0]} problems, {c['cpu_s']:.1f} CPU s"
                     for c in calls)
         + (f". Reference: each problem's cost after {args.ref} fixed iterations (x n_iter / 200); gaps relative to it."), "",
         ("| candidate@start | zone | free | iters (rtol 1e-10) | cap hit | falling at ref | gap @30 | @60 | @100 | "
          "@cap | iters / gap at rtol 1e-8 | 1e-7 | 1e-6 |"), "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in problems:
        g = p["gap_cut"]
        L.append(f"| {p['label']} | {p['zone']} | {p['free']} | {p['iters']} | {'**yes**' if p['hit_cap'] else ''} | "
                 f"{'yes' if p['still_falling_at_ref'] else ''} | {g['30']:.1e} | {g['60']:.1e} | {g['100']:.1e} | "
                 f"{g[str(p['n_iter'])]:.1e} | "
                 + " | ".join(f"{p['rtol'][r]['iters']} / {p['rtol'][r]['gap']:.1e}" for r in ("1e-08", "1e-07", "1e-06"))
                 + " |")
    hits = [p for p in problems if p["hit_cap"]]
    L += ["", (f"{len(hits)} of {len(problems)} problems hit the cap: "
               + ", ".join(f"{p['label']} z{p['zone']}" for p in hits)), "",
          ("Per candidate (each zone its best start): likelihood-ratio shift m log(SSE / SSE_ref), "
           f"m = T n = {T * n}, and the iterations the variant spends in all (Jacobians at most that)."), "",
          "| variant | iterations | " + " | ".join(cands) + " |", "|---|---|" + "---|" * len(cands)]
    for r in cand_rows:
        L.append(f"| {r['variant']} | {r['iterations']} | " + " | ".join(f"{r['lr_shift'][m]:.3g}" for m in cands) + " |")
    L += ["", "Diagnosis's estimation LRs: " + ", ".join(f"{k} {v}" for k, v in diag["candidates"].items())]
    RESULTS.mkdir(exist_ok=True)
    atomic_write_text(RESULTS / "diagnose_zone_convergence.md", "\n".join(L) + "\n")
    atomic_write_text(RESULTS / "diagnose_zone_convergence.json", json.dumps(out))
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    sys.exit(main())
