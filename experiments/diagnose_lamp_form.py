"""Which static input curve explains a held-out saturating lamp (issue 14, held-out set 12 case 08)?

The library's `input_nonlinearity` is one static curve $q(u)$ with one parameter $e$ (the
parameter `log_e`, $e = 1$ linear). This script runs the held-out diagnosis of one case
(`diagnose_heldout_hard.draw_case`) with the curve swapped in for the experiment:

| `--form` | $q(u)$ |
| --- | --- |
| `power` | $u^e$ (the library before issue 14's lamp case) |
| `rational` | $e\\,u / (1 + (e - 1) u)$: $q(0) = 0$, $q(1) = 1$, slope $e$ at 0 and $1/e$ at 1 |
| `exp` | $(1 - e^{-\\beta u}) / (1 - e^{-\\beta})$, $\\beta = 2 \\log e$: the generator's own lamp (oracle) |
| `power_n`, `rational_n` | the same curves normalised to pass through the estimation record's mean input $u_m$ whatever $e$ (the rational one on the record's full scale, its largest input): the same model class, the gain no longer trades with $e$ |
| `library` | whatever `mechanisms.py` holds now (no swap) |

    .venv/bin/python experiments/diagnose_lamp_form.py --case 8 --seed-set 12 --form rational

Prints (and writes `experiments/results/diagnose_lamp_form_<case>_set<S>_<form>.md`) what was
named, every candidate's tests, the validation MSE reduction and the input range the record
visits.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np

from jthermo.data import atomic_write_text
from jthermo.diagnose import diagnose, to_json
from jthermo.diagnose import mechanisms as M

sys.path.insert(0, str(Path(__file__).resolve().parent))
import diagnose_heldout_hard as H


def _pos(u):
    return jnp.where(u > 1e-12, u, 0.0)


def _power(u, e):
    pos = u > 1e-12
    return jnp.where(pos, jnp.where(pos, u, 1.0) ** e, 0.0)


def _rational(u, e):
    u = _pos(u)
    return e * u / (1.0 + (e - 1.0) * u)


def _exp(u, e):
    u = _pos(u)
    beta = 2.0 * jnp.log(e)
    small = jnp.abs(beta) < 1e-4
    b = jnp.where(small, 1.0, beta)
    # near beta = 0 its Taylor series (a gradient there, so a fit can leave the linear start)
    return jnp.where(small, u + 0.5 * beta * u * (1.0 - u), jnp.expm1(-b * u) / jnp.expm1(-b))


FORMS = {"power": _power, "rational": _rational, "exp": _exp}
#: the estimation record's mean and largest input, set by `main` (the normalised forms)
REF = {"mean": 1.0, "max": 1.0}


def _power_n(u, e):
    """$u_m (u / u_m)^e$: the power curve through the record's mean input whatever $e$."""
    m = REF["mean"]
    return m * _power(u / m, e)


def _rational_n(u, e):
    """The rational curve on the record's full scale $u_s$, through the mean input whatever $e$."""
    s, m = REF["max"], REF["mean"]
    return _rational(u / s, e) / _rational(jnp.asarray(m / s), e) * m


FORMS.update(power_n=_power_n, rational_n=_rational_n)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", type=int, required=True)
    ap.add_argument("--seed-set", type=int, default=0)
    ap.add_argument("--max-zones", type=int, default=9)
    ap.add_argument("--kind", default=None, help="force the case's kind (default: its cycle's)")
    ap.add_argument("--form", choices=sorted(FORMS) + ["library"], default="library")
    ap.add_argument("--out", default="experiments/results")
    args = ap.parse_args(argv)
    if args.form != "library":
        M._safe_pow = FORMS[args.form]
    c = H.draw_case(args.case, args.kind, args.max_zones, args.seed_set)
    est, val = H.make_record(c)
    REF.update(mean=float(np.mean(est.u)), max=float(np.max(est.u)))
    t0, c0 = time.perf_counter(), os.times()
    res = to_json(diagnose(est, val))
    wall = time.perf_counter() - t0
    cpu = sum(os.times()[:2]) - sum(c0[:2])
    u = np.asarray(est.u)
    name = f"diagnose_lamp_form_{args.case:02d}_set{args.seed_set}_{args.form}"
    cmd = (f"python experiments/diagnose_lamp_form.py --case {args.case} --seed-set {args.seed_set} "
           f"--max-zones {args.max_zones}{' --kind ' + args.kind if args.kind else ''} --form {args.form}")
    lines = [f"# Held-out case {args.case:02d} ({c['kind']}), seed set {args.seed_set}, input curve `{args.form}`", "",
             f"Made by `{cmd}`; {wall:.0f} s wall, {cpu:.0f} CPU s, 1-min load {os.getloadavg()[0]:.1f}.", "",
             (f"- record: N = {c['zones']}, Ts = {c['ts']:.3f} s, noise {c['noise']:.3f} °C, measured surroundings "
              f"{c['measured_ambient']}; physics {json.dumps(H.describe(c))}"),
             (f"- estimation inputs: min {u.min():.3f}, 5 % {np.quantile(u, 0.05):.3f}, median "
              f"{np.median(u):.3f}, 95 % {np.quantile(u, 0.95):.3f}, max {u.max():.3f}"),
             f"- named {[(f['mechanism'], round(f['confidence'], 3), f['rivals']) for f in res['findings']]}",
             f"- fit {res['baseline']['mean_fit_percent']:.2f} → {res['augmented']['mean_fit_percent']:.2f} %", "",
             ("| candidate | validation z / critical | estimation LR / critical | significant | "
              "validation MSE reduction | parameters |"), "|---|---|---|---|---|---|"]
    for r in res["candidates"]:
        lines.append(f"| {r['mechanism']} | {r['validation_z']:.3f} / {r['validation_z_critical']:.2f} | "
                     f"{r['estimation_lr']:.2f} / {r['estimation_lr_critical']:.2f} | {r['significant']} | "
                     f"{r['val_reduction']:.4f} | {json.dumps(r['parameters'], default=float)[:120]} |")
    atomic_write_text(Path(args.out) / f"{name}.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
