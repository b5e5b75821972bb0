"""Damping, step and acceleration variants of the masked Levenberg–Marquardt replayed on the
diagnosis's own per-zone problems (the same minima in fewer iterations?).

`--capture REC`: runs `select.diagnose` on a record (`latency` or `dev:S:I`, as
`diagnose_zone_convergence.py`) and stores every `fitting.fit_zones` call's arguments and its
costs (production `identify.lm.masked_lm`) under `--store` (not committed: arrays).

Replay (default): each stored problem is fitted again, one after another (`lax.map`, as
`fitting._fit_zones`), by `variant_lm` below under each variant, with the production stop
(`fitting.RTOL` over `lm.STALL` iterations, at most the call's `n_iter`); per problem its final
cost, iterations and Jacobians. Per variant: the problems whose cost is above the baseline's
(relative, beyond 1e-9), the worst relative excess, each (candidate set x start) block's estimation
statistic shift m log(SSE / SSE_base) (its zones' costs summed), total iterations and Jacobians, CPU s of the run.

    python benchmarks/lm_variants.py --capture latency
    python benchmarks/lm_variants.py --records latency,dev:12:08 --variants base,nielsen

Writes `benchmarks/results/lm_variants.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import sys
from pathlib import Path

from common import cpu_seconds  # noqa: E402

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from jthermo.data import atomic_write_text
from jthermo.diagnose import fitting, select
from jthermo.identify.lm import STALL

STORE = Path("/tmp/lm_variants_store")

#: variant name -> options of `variant_lm`
VARIANTS = {
    "base": {},
    "nielsen": {"rule": "nielsen"},
    "nielsen3": {"rule": "nielsen3"},
    "wide5": {"trials": (0.01, 0.1, 1.0, 10.0, 100.0)},
    "scaleclip": {"clip": "scale"},
    "noclip5": {"clip": "elem", "clip_to": 5.0},
    "geo": {"geo": True},
    "extrap": {"extrap": (2.0, 4.0)},
    "extrap_scale": {"extrap": (2.0, 4.0), "clip": "scale"},
    "geo_scale": {"geo": True, "clip": "scale"},
    "down3": {"down": 1.0 / 3.0, "up": 10.0},
    "geo_extrap": {"geo": True, "extrap": (2.0, 4.0)},
    "geo1": {"geo_extra": (1.0,)},
    "geo1_01": {"geo_extra": (0.1,)},
    "geo1_extrap": {"geo_extra": (1.0,), "extrap": (2.0,)},
}


def variant_lm(residual, theta0, mask, n_iter, n_active, rtol, trials=(0.1, 1.0, 10.0), down=0.5, up=30.0,
               rule="marquardt", clip="elem", clip_to=2.0, geo=False, extrap=(), geo_extra=()):
    """`identify.lm.masked_lm(..., rtol=...)` (defaults: the same iterates) with options:
    `rule` "nielsen": the kept trial's λ scaled by max(1/3, 1-(2ρ-1)^3) (ρ gain ratio) instead of
    `down`, ν doubling on failures; "nielsen3": the same but only for ρ, trials as given;
    `clip` "scale": the whole step scaled so its largest entry is `clip_to` (direction kept);
    `geo`: geodesic acceleration (Transtrum) added to each trial, if 2|a|/|v| <= 0.75;
    `geo_extra`: extra trials at these multipliers with the acceleration;
    `extrap`: the best trial's step also tried times these factors. Returns (θ, cost, k, n_jac)."""
    dt = theta0.dtype
    P = theta0.shape[0]
    na = n_active
    idx = jnp.nonzero(mask > 0, size=na, fill_value=0)[0]
    valid = (jnp.arange(na) < jnp.sum(mask > 0)).astype(dt)
    tangents = jax.nn.one_hot(idx, P, dtype=dt) * valid[:, None]

    def cost(th):
        c = jnp.mean(residual(th) ** 2)
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    def linear(th):
        r, jvp = jax.linearize(residual, th)
        J = jax.vmap(jvp, out_axes=1)(tangents)
        return r, jnp.where(jnp.isfinite(J), J, 0.0)

    def clipd(delta):
        if clip == "scale":
            mx = jnp.max(jnp.abs(jnp.where(jnp.isfinite(delta), delta, 0.0)))
            delta = delta * jnp.minimum(1.0, clip_to / jnp.maximum(mx, 1e-300))
        else:
            delta = jnp.clip(delta, -clip_to, clip_to)
        return jnp.where(jnp.isfinite(delta), delta * valid, 0.0)

    def update(th, c_now, lam, nu, r, J):
        H = J.T @ J
        gvec = J.T @ r
        d = jnp.diagonal(H)
        scale = jnp.where(valid > 0, d + 1e-9 * (jnp.max(d) + 1e-30), 1.0)
        Hm = H * (valid[:, None] * valid[None, :]) + jnp.diag(1.0 - valid)

        def step(lm, use_geo=geo):
            A = Hm + lm * jnp.diag(scale)
            v = -jnp.linalg.solve(A, gvec * valid)
            if use_geo:
                vf = jnp.zeros(P, dt).at[idx].add(jnp.where(jnp.isfinite(v), v * valid, 0.0))
                h = 0.1
                rpp = (2.0 / h) * ((residual(th + h * vf) - r) / h - J @ (v * valid))
                rpp = jnp.where(jnp.isfinite(rpp), rpp, 0.0)
                a = -jnp.linalg.solve(A, (J.T @ rpp) * valid)
                ok = 2.0 * jnp.linalg.norm(a) <= 0.75 * jnp.linalg.norm(v)
                v = jnp.where(ok, v + 0.5 * a, v)
            raw = v
            delta = clipd(v)
            tn = th.at[idx].add(delta)
            pred = -(2 * delta @ (gvec * valid) + delta @ (Hm @ delta))    # predicted fall of sum r^2
            return tn, cost(tn), delta, pred, raw

        lams = lam * jnp.array(trials, dt)
        tns, cs, ds, preds, _ = jax.vmap(step)(lams)
        if geo_extra:
            lg = lam * jnp.array(geo_extra, dt)
            g = jax.vmap(lambda q: step(q, True))(lg)
            lams = jnp.concatenate([lams, lg])
            tns, cs, ds, preds = (jnp.concatenate([a, b]) for a, b in zip((tns, cs, ds, preds), g[:4]))
        k = jnp.argmin(cs)
        tn, cn, dk, lk = tns[k], cs[k], ds[k], lams[k]
        if extrap:
            fs = jnp.array(extrap, dt)
            tx = jax.vmap(lambda f: th.at[idx].add(clipd(f * dk)))(fs)
            cx = jax.vmap(cost)(tx)
            j = jnp.argmin(cx)
            use = cx[j] < cn
            tn, cn = jnp.where(use, tx[j], tn), jnp.where(use, cx[j], cn)
        better = cn < c_now
        m = r.shape[0]
        if rule in ("nielsen", "nielsen3"):
            rho = (c_now - cs[k]) * m / jnp.maximum(preds[k], 1e-300)
            fac = jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            lam_ok = lk * fac
            lam_bad = lam * nu
            nu_new = jnp.where(better, 2.0, nu * 2.0)
        else:
            lam_ok, lam_bad, nu_new = lk * down, lam * up, nu
        th = jnp.where(better, tn, th)
        lam = jnp.where(better, jnp.clip(lam_ok, 1e-9, 1e9), jnp.clip(lam_bad, 1e-9, 1e9))
        return th, jnp.where(better, cn, c_now), lam, nu_new, better

    c0 = cost(theta0)

    def more(carry):
        _, c, lam, _, k, hist, _, _, _, _ = carry
        back = hist[jnp.maximum(k - 1 - STALL, 0)]
        stalled = (k > STALL) & (back - c <= rtol * jnp.abs(back))
        return (k < n_iter) & ~stalled & (lam < 1e9)

    def body(carry):
        th, c, lam, nu, k, hist, r, J, moved, nj = carry
        r, J = jax.lax.cond(moved, linear, lambda _: (r, J), th)
        nj = nj + moved.astype(jnp.int32)
        th, c, lam, nu, moved = update(th, c, lam, nu, r, J)
        return th, c, lam, nu, k + 1, hist.at[k].set(c), r, J, moved, nj

    r0 = jax.eval_shape(residual, theta0)
    carry = (theta0, c0, jnp.asarray(1e-2, dt), jnp.asarray(2.0 if rule.startswith("nielsen") else up, dt),
             jnp.asarray(0, jnp.int32), jnp.full(n_iter, c0, dt), jnp.zeros(r0.shape, r0.dtype),
             jnp.zeros(r0.shape + (na,), r0.dtype), jnp.asarray(True), jnp.asarray(0, jnp.int32))
    th, c, _, _, k, _, _, _, _, nj = jax.lax.while_loop(more, body, carry)
    return th, c, k, nj


def _replay(theta0, mask, on, per, shared, lay, n_iter, n_active, opts):
    def one(a):
        t, m, o, p = a
        z = {**shared, **p}
        return variant_lm(lambda th: fitting._zone_residual(th, o, z, lay), t, m, n_iter, n_active,
                          fitting.RTOL, **dict(opts))

    return jax.lax.map(one, (theta0, mask, on, per))


_replay_jit = jax.jit(_replay, static_argnames=("lay", "n_iter", "n_active", "opts"))



def capture(spec: str, max_zones: int) -> None:
    from diagnose_zone_convergence import load_record

    est, val = load_record(spec, max_zones)
    calls = []
    orig = select.fit_zones

    def spy(*a):
        out = orig(*a)
        calls.append({"args": jax.tree_util.tree_map(np.asarray, a[:5]) + tuple(a[5:]),
                      "cost": np.asarray(out[1])})
        return out

    select.fit_zones = spy
    res = select.to_json(select.diagnose(est, val))
    select.fit_zones = orig
    STORE.mkdir(exist_ok=True)
    with open(STORE / f"{spec.replace(':', '_')}.pkl", "wb") as f:
        pickle.dump({"calls": calls, "T": est.n_samples, "n": est.n_outputs,
                     "findings": [(x["mechanism"], x["confidence"]) for x in res["findings"]]}, f)
    print(spec, [c["args"][0].shape for c in calls], res["findings"] and [x["mechanism"] for x in res["findings"]])


def run_variant(calls, opts):
    out = []
    c0 = cpu_seconds()
    for call in calls:
        theta0, mask, on, per, shared, lay, n_iter, n_active = (list(call["args"]) + [None])[:8]
        if n_active is None:
            n_active = theta0.shape[1]
        th, c, k, nj = _replay_jit(jnp.asarray(theta0), jnp.asarray(mask), jnp.asarray(on),
                                   jax.tree_util.tree_map(jnp.asarray, per),
                                   jax.tree_util.tree_map(jnp.asarray, shared), lay, n_iter, n_active,
                                   tuple(sorted(opts.items())))
        out.append({"cost": np.asarray(c), "iters": np.asarray(k), "jac": np.asarray(nj)})
    return out, cpu_seconds() - c0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--capture", default=None)
    ap.add_argument("--max-zones", type=int, default=9)
    ap.add_argument("--records", default="latency")
    ap.add_argument("--variants", default="base,nielsen")
    args = ap.parse_args(argv)
    if args.capture:
        for s in args.capture.split(","):
            capture(s, args.max_zones)
        return 0
    rows, L = [], ["# Masked LM variants on the diagnosis's per-zone problems", "",
                   f"`python benchmarks/lm_variants.py --records {args.records} --variants {args.variants}"
                   f"` (load {os.getloadavg()[0]:.1f}). Excess: problems "
                   "whose final cost is above the baseline's by more than 1e-9 relative; LR shift: each (candidate set x start) "
                   "block's m log(SSE/SSE_base), its zones' costs summed (min / max over blocks, negative = lower cost). "
                   "CPU s: the replay run (second call, compiled).", "",
                   "| record | variant | iterations | Jacobians | problems above base | worst rel. excess | "
                   "min / max LR shift | CPU s |", "|---|---|---|---|---|---|---|---|"]
    for spec in args.records.split(","):
        with open(STORE / f"{spec.replace(':', '_')}.pkl", "rb") as f:
            rec = pickle.load(f)
        calls = rec["calls"]
        base = None
        for vn in args.variants.split(","):
            opts = VARIANTS[vn]
            run_variant(calls, opts)                      # compile
            res, cpu = run_variant(calls, opts)
            cost = np.concatenate([r["cost"] for r in res])
            if vn == "base":
                prod = np.concatenate([c["cost"] for c in calls])
                print(spec, "base vs production max rel diff", float(np.max(np.abs(cost - prod) / prod)))
                base = cost
            rel = (cost - base) / base
            # LR shift per candidate: problems of call 0 grouped by label order is not stored; use all
            # problems of each call as (start-major, zone-minor) blocks and the zone's best over starts
            shifts = []
            off = 0
            for call in calls:
                B = call["args"][0].shape[0]
                n = rec["n"]
                cb, cv = base[off:off + B].reshape(-1, n), cost[off:off + B].reshape(-1, n)
                for s in range(cb.shape[0]):
                    shifts.append(float(rec["T"] * n * np.log(cv[s].sum() / cb[s].sum())))
                off += B
            row = {"record": spec, "variant": vn, "iters": int(sum(r["iters"].sum() for r in res)),
                   "jac": int(sum(r["jac"].sum() for r in res)), "n_above": int(np.sum(rel > 1e-9)),
                   "worst_excess": float(rel.max()), "lr_min": min(shifts), "lr_max": max(shifts), "cpu_s": cpu,
                   "cost": cost.tolist(), "iters_each": np.concatenate([r["iters"] for r in res]).tolist()}
            rows.append(row)
            line = (f"| {spec} | {vn} | {row['iters']} | {row['jac']} | {row['n_above']} / {cost.size} | "
                    f"{row['worst_excess']:.1e} | {row['lr_min']:.3g} / {row['lr_max']:.3g} | {cpu:.1f} |")
            L.append(line)
            print(line, flush=True)
    L += ["", "LR shift here is per (candidate set x start) block summed over zones (not the zone-best "
          "combination): positive = that block's fits cost more than the baseline's."]
    atomic_write_text(HERE / "results" / "lm_variants.md", "\n".join(L) + "\n")
    atomic_write_text(HERE / "results" / "lm_variants.json", json.dumps(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
