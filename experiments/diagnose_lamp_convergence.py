"""Why a held-out saturating lamp was named `radiative_loss` at 0.999 (issue 14, set 12 case 08).

Runs the diagnosis of one held-out case (`diagnose_heldout_hard.draw_case`) with two candidates,
`radiative_loss` and `input_nonlinearity`, and prints per zone the estimation and validation
MSE of each candidate's fitted model, the Diebold–Mariano $z$ of each against the other on the
validation record (`decide.predictive_z`: what ranks them and forms the confidence), and, for one
zone, the lamp fit's cost and free parameters after 1 ... `--trace-iters` Levenberg–Marquardt
iterations (the same solve, stopped earlier). `--form` swaps the input curve as
`diagnose_lamp_form.py`; `--n-iter` the per-zone iteration cap.

    .venv/bin/python experiments/diagnose_lamp_convergence.py --case 8 --seed-set 12 --trace-zone 2
    .venv/bin/python experiments/diagnose_lamp_convergence.py --case 8 --seed-set 12 --n-iter 1500

Writes `experiments/results/diagnose_lamp_convergence_<case>_set<S>_<form>_it<N><tag>.md`.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

import jthermo.diagnose.select as S
from jthermo.data import atomic_write_text
from jthermo.diagnose import decide as D
from jthermo.diagnose import diagnose
from jthermo.diagnose import mechanisms as M

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H
import diagnose_lamp_form as F

MECHS = ("radiative_loss", "input_nonlinearity")


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", type=int, default=8)
    ap.add_argument("--seed-set", type=int, default=12)
    ap.add_argument("--max-zones", type=int, default=9)
    ap.add_argument("--form", choices=sorted(F.FORMS) + ["library"], default="library")
    ap.add_argument("--n-iter", type=int, default=S.N_ITER)
    ap.add_argument("--trace-zone", type=int, default=0, help="1-based zone whose lamp fit is traced")
    ap.add_argument("--trace-iters", default="1,10,25,50,100,150,200,300,400")
    ap.add_argument("--tag", default="")
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    if args.form != "library":
        M._safe_pow = F.FORMS[args.form]
    c = H.draw_case(args.case, "lamp_saturation", args.max_zones, args.seed_set)
    est, val = H.make_record(c)
    F.REF.update(mean=float(np.mean(est.u)), max=float(np.max(est.u)))
    n = c["zones"]
    calls = []
    fit_zones = S.fit_zones
    S.fit_zones = lambda *a, **k: calls.append(a) or fit_zones(*a, **k)
    t0, c0 = time.perf_counter(), os.times()
    res = diagnose(est, val, mechanisms=MECHS, n_iter=args.n_iter)
    wall, cpu = time.perf_counter() - t0, sum(os.times()[:2]) - sum(c0[:2])
    S.fit_zones = fit_zones
    ev, ee = res["_arrays"]["resid_val"], res["_arrays"]["resid_est_candidates"]
    cmd = (f"python experiments/diagnose_lamp_convergence.py --case {args.case} --seed-set {args.seed_set} "
           f"--max-zones {args.max_zones} --form {args.form} --n-iter {args.n_iter}"
           + (f" --trace-zone {args.trace_zone}" if args.trace_zone else ""))
    lines = [(f"# Held-out case {args.case:02d} (lamp_saturation), set {args.seed_set}: radiation against the lamp "
              f"curve `{args.form}`, {args.n_iter} iterations{' ' + args.tag if args.tag else ''}"), "",
             f"Made by `{cmd}`; {wall:.0f} s wall, {cpu:.0f} CPU s (diagnosis), 1-min load {os.getloadavg()[0]:.1f}.", "",
             (f"- record: N = {n}, noise {c['noise']:.3f} °C (variance {c['noise'] ** 2:.5f}), beta {c['beta']:.3f}, "
              f"rises {np.round(c['B'].diagonal() / c['a'], 1).tolist()} K, time constants {np.round(1 / c['a']).tolist()} s"),
             f"- named {[(f['mechanism'], round(f['confidence'], 3), f['rivals']) for f in res['findings']]}",
             "- validation MSE reduction: " + ", ".join(f"{r['mechanism']} {r['val_reduction']:.4f}" for r in res["candidates"]),
             (f"- z radiation over lamp {D.predictive_z(ev['input_nonlinearity'], ev['radiative_loss']):.3f}, "
              f"lamp over radiation {D.predictive_z(ev['radiative_loss'], ev['input_nonlinearity']):.3f}"), "",
             "| MSE per zone (°C²) | " + " | ".join(str(i + 1) for i in range(n)) + " |", "|---" * (n + 1) + "|"]
    for rec, arrs in (("validation", ev), ("estimation", ee)):
        for m in (("baseline",) if rec == "validation" else ()) + MECHS:
            lines.append(f"| {rec} {m} | " + " | ".join(f"{v:.5f}" for v in np.mean(arrs[m] ** 2, axis=0)) + " |")
    if args.trace_zone:
        th0, mask, on, per, shared, lay, _, nact = calls[0]
        b = MECHS.index("input_nonlinearity") * n + args.trace_zone - 1
        one = lambda x: x[b:b + 1]
        names = [nm for nm, _, s in lay.sections for _ in range(s)]
        free = np.nonzero(np.asarray(mask[b]))[0]
        lines += ["", f"Lamp fit of zone {args.trace_zone} stopped after k iterations (free parameters):", "",
                  "| k | cost | " + " | ".join(names[i] for i in free) + " |", "|---" * (len(free) + 2) + "|"]
        for k in (int(v) for v in args.trace_iters.split(",")):
            t, cst, _ = S.fit_zones(one(th0), one(mask), one(on), jax.tree_util.tree_map(one, per), shared, lay, k, nact)
            t = np.asarray(t)[0]
            lines.append(f"| {k} | {float(np.asarray(cst)[0]):.5f} | " + " | ".join(f"{t[i]:.3f}" for i in free) + " |")
    name = f"diagnose_lamp_convergence_{args.case:02d}_set{args.seed_set}_{args.form}_it{args.n_iter}{args.tag}"
    atomic_write_text(Path(args.out) / f"{name}.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
