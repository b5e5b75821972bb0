"""Slow body against surroundings drift: the statistics the diagnosis orders them by, per case
(issue 14). For each `CASE:SET` of the harder held-out study (`diagnose_heldout_hard.draw_case`,
at most 3 zones): the top findings with confidence and rivals, every localisation figure about
the drift and the body (own-vs-common drift likelihood ratios, agreement z, input dependence z
per record, `drift_over_body_z`: the whitened Diebold-Mariano z that the drift out-predicts the
body on the validation record beyond its extra re-estimated parameters) and the two candidates'
rows (validation z, estimation LR, validation MSE, fit, parameters). One block per case:

    python experiments/diagnose_slow_probe.py 4:10 4:8 4:6 13:8 14:10 5:10 5:8 > OUT
"""

from __future__ import annotations

import os
import sys

import jax

jax.config.update("jax_enable_x64", True)

from jthermo.diagnose import diagnose

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import diagnose_heldout_hard as H

SLOW = ("heat_accumulation", "ambient_variation")
ROW = ("mechanism", "validation_z", "validation_z_critical", "estimation_lr", "estimation_lr_critical",
       "significant", "val_mse", "mean_fit_percent", "parameters")
CASE = ("body_tau", "body_share", "body_start", "drift_C", "drift_period_s")


def probe(spec: str) -> None:
    case, seed_set = (int(v) for v in spec.split(":"))
    c = H.draw_case(case, None, 3, seed_set)
    est, val = H.make_record(c)
    r = diagnose(est, val)
    loc = r["localisation"]
    print("=====", spec, c["kind"], "N", c["zones"], "ts", round(c["ts"], 2), {k: c.get(k) for k in CASE})
    print("top", [(f["mechanism"], f.get("confidence"), f.get("rivals")) for f in r["findings"][:3]])
    for k in loc:
        if "drift" in k or "body" in k or "input" in k:
            print("  ", k, loc[k])
    for row in r.get("candidates", []):
        if row["mechanism"] in SLOW:
            print("  cand", {k: row.get(k) for k in ROW})
    sys.stdout.flush()


if __name__ == "__main__":
    for spec in sys.argv[1:]:
        probe(spec)
        jax.clear_caches()          # compiled code's memory maps would pile up (heldout_hard)
