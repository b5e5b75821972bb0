"""Does testing the validation record's drift for input dependence change a real diagnosis?

`select.diagnose` orders a slow body and an unmeasured drift by `decide.combined_dependence` over
the estimation record's fitted drift and the drift re-estimated on the validation record (each
record tested only with at least 8 drift knots, 2400 s). Before, only the estimation record's test
counted. On the real recordings of `experiments/diagnose_study.py` each diagnosis is run twice:
as is, and with the validation record's test left out (the former rule); findings, rivals and
confidence are compared.

    .venv/bin/python experiments/body_drift_validation_check.py

Writes `experiments/results/body_drift_validation_check.md`.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from jthermo.data import atomic_write_text, load, split
from jthermo.diagnose import decide as D
from jthermo.diagnose import select as S
from jthermo.diagnose import to_json

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / ".." / "shared" / "data" / "real"


def former(zs, testable):
    """The former rule: the estimation record's statistic alone (0 when it cannot be tested)."""
    return float(zs[0]) if testable[0] else 0.0


def brief(res):
    f = res["findings"]
    return {"findings": [x["mechanism"] for x in f], "rivals": f[0]["rivals"] if f else [],
            "confidence": round(f[0]["confidence"], 4) if f else None,
            "z": res["localisation"].get("drift_input_dependence_records_z"),
            "z_used": res["localisation"].get("drift_input_dependence_z")}


def main():
    d = load(REAL / "tclab_rawlings" / "prbs_kr2022" / "data.csv")
    pairs = [("tclab_rawlings prbs_kr2022 (2/3 | 1/3)", *split(d, 2 / 3)),
             ("tclab_cace2020 id_2heaters -> val_2heaters", load(REAL / "tclab_cace2020" / "id_2heaters" / "data.csv"),
              load(REAL / "tclab_cace2020" / "val_2heaters" / "data.csv"))]
    lines = ["# Validation-record input dependence on the real recordings", "",
             "Made by `experiments/body_drift_validation_check.py`. Each diagnosis with the validation",
             "record's input-dependence test (now) and without it (the former rule).", "",
             ("| data | val s | val testable | now: findings (rivals) conf | former: findings (rivals) conf | "
              "z est / val | z used now / former | same |"), "|---|---|---|---|---|---|---|---|"]
    keep = S.D.combined_dependence
    for name, est, val in pairs:
        t0 = time.perf_counter()
        now = brief(to_json(S.diagnose(est, val)))
        S.D.combined_dependence = former
        try:
            old = brief(to_json(S.diagnose(est, val)))
        finally:
            S.D.combined_dependence = keep
        same = (now["findings"], now["rivals"], now["confidence"]) == (old["findings"], old["rivals"],
                                                                      old["confidence"])
        testable = D.dependence_testable(val.n_samples, round(300.0 / val.ts))
        fmt = lambda b: f"{', '.join(b['findings']) or '-'} ({', '.join(b['rivals']) or '-'}) {b['confidence']}"
        zs = now["z"] or [float("nan"), float("nan")]
        lines.append(f"| {name} | {val.n_samples * val.ts:.0f} | {'yes' if testable else 'no'} | {fmt(now)} | "
                     f"{fmt(old)} | {zs[0]:.2f} / {zs[1]:.2f} | {now['z_used']} / {old['z_used']} | "
                     f"{'yes' if same else 'NO'} |")
        print(lines[-1], f"({time.perf_counter() - t0:.0f} s)", flush=True)
    lines += ["", "Load average (1, 5, 15 min): " + ", ".join(f"{v:.2f}" for v in os.getloadavg()), ""]
    atomic_write_text(ROOT / "experiments" / "results" / "body_drift_validation_check.md", "\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
