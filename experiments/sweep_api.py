"""A sweep scripted as an engineer would: an ARX order grid on a real
recording (default the DaISy heating system, `../shared/data/real/daisy_heating_system`;
`--record tclab_apm_mimo_steps` for the two-heater TCLab steps), run in process
with `jthermo.sweep`, read back as a pandas DataFrame, and checked against `identify.fit` +
`validate.compare` called directly on the same halves: the sweep's score must be the same
number (its `arx` kind was a separate NumPy ARX before). Also records that the in-process
sweep left JAX's global `jax_enable_x64` as the caller had it.

    .venv/bin/python experiments/sweep_api.py [--record NAME]
    -> experiments/results/sweep_api.{json,md}
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import jax

from jthermo import sweep
from jthermo.data import load, split
from jthermo.identify import fit
from jthermo.sweep.tasks import float64
from jthermo.validate import compare

ROOT = Path(__file__).resolve().parent.parent
REAL = Path("..") / "shared" / "data" / "real"

CONFIG = """
[sweep]
name = "tclab-arx"
kind = "arx"
[data]
data = "{data}"
[space]
na = [1, 2, 3]
nb = [1, 2, 3]
nk = [1, 2]
"""


def main(name: str) -> dict:
    os.chdir(ROOT)           # the record path is repository-relative
    record = REAL / name / "data.csv"
    out = Path("experiments") / "results" / "sweep_api"
    x64_before = bool(jax.config.jax_enable_x64)
    cfg = sweep.parse_config(CONFIG.format(data=record.as_posix()))
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        rep = sweep.run_sweep(cfg, Path(tmp) / "r.jsonl")
        df = rep.to_dataframe()
    wall = time.perf_counter() - t0
    x64_after = bool(jax.config.jax_enable_x64)
    best = df.iloc[0]
    orders = (int(best.na), int(best.nb), int(best.nk))
    est, val = split(load(record), 0.5)
    with float64():
        direct = compare(fit(est, "arx", orders).model, val)["mean_fit_percent"]
    cols = ["na", "nb", "nk", "mean_fit_percent", *sorted(c for c in df if c.startswith("fit_percent_")), "seconds"]
    result = {
        "record": record.as_posix(), "trials": int(rep["n_total"]), "failed": int(rep["n_failed"]),
        "sweep_wall_s": wall, "load_average": os.getloadavg(),
        "best_orders": orders, "best_sweep_fit_percent": float(best.mean_fit_percent),
        "direct_fit_compare_percent": float(direct),
        "errors": {str(k): int(v) for k, v in df.error.dropna().str.slice(0, 90).value_counts().items()},
        "same_number": abs(float(best.mean_fit_percent) - float(direct)) < 1e-9,
        "jax_enable_x64_before_after": [x64_before, x64_after],
        "table": json.loads(df[cols].to_json(orient="records")),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    md = [f"# Sweep API check: ARX orders on `{result['record']}`", "",
          (f"{result['trials']} trials ({result['failed']} failed) in {wall:.1f} s wall "
           f"(load average {result['load_average'][0]:.1f}, a shared 2-core machine: inflated)."),
          (f"Best orders {orders}: sweep {result['best_sweep_fit_percent']:.3f} %, "
           f"`fit` + `compare` directly {direct:.3f} % (same number: {result['same_number']})."),
          f"`jax_enable_x64` before / after the in-process sweep: {x64_before} / {x64_after}.",
          *(f"- {n} trial(s) refused by `fit`: {e}" for e, n in result["errors"].items()),
          "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    md += ["| " + " | ".join(f"{r[c]:.2f}" if isinstance(r[c], float) else str(r[c]) for c in cols)
           + " |" for r in result["table"][:8]]
    out.with_suffix(".md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return result


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--record", default="daisy_heating_system",
                    help="a folder of ../shared/data/real holding data.csv")
    main(ap.parse_args().record)
