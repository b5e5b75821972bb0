"""`make demo`'s diagnosis stage alone: the same record, the same call, timed.

The demo (`jthermo/demo.py`, full settings, seed 0) conceals a 25 s heater lag in a 4-zone
virtual printer, records one hour of PRBS (estimation) and 30 minutes (validation) and
diagnoses them. This script repeats exactly that stage in one process, without the rest of the
demo, and reports the finding (lamp lag in s), the mean validation fit baseline → augmented and
the time (wall s, CPU s = user + system of the process, the 1-minute load before and after).

    python benchmarks/diagnose_demo_stage.py [--tag _after]

Writes `benchmarks/results/diagnose_demo_stage{tag}.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def _cpu() -> float:
    t = os.times()
    return t.user + t.system


def _load() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def run(seed: int = 0) -> dict:
    """Diagnose the demo's concealed-effect record; returns the figures of the table."""
    load0, c0, w0 = _load(), _cpu(), time.perf_counter()
    import jax

    from jthermo import runtime

    runtime.enable_cache()          # as the `jthermo` command sets up JAX
    runtime.unroll_threefry()
    jax.config.update("jax_enable_x64", True)
    from jthermo.demo import CONCEALED, SETTINGS
    from jthermo.diagnose import diagnose
    from jthermo.printer import generate, make_printer

    cfg = SETTINGS["full"]
    eff_name, eff_params = CONCEALED
    p = make_printer(cfg["zones"], {eff_name: eff_params}, seed=seed + 5)
    d_est = generate(p, "prbs", cfg["diag_est_s"], seed=seed + 7)
    d_val = generate(p, "prbs", cfg["diag_val_s"], seed=seed + 8)
    c1, w1 = _cpu(), time.perf_counter()
    res = diagnose(d_est, d_val, seed=seed)
    c2, w2 = _cpu(), time.perf_counter()
    return {"concealed": {"mechanism": eff_name, **eff_params},
            "verdict": res["verdict"],
            "findings": [f["mechanism"] for f in res["findings"]],
            "parameters": [f["parameters"] for f in res["findings"]],
            "baseline_fit_percent": res["baseline"]["mean_fit_percent"],
            "augmented_fit_percent": res["augmented"]["mean_fit_percent"],
            "diagnose_wall_s": w2 - w1, "diagnose_cpu_s": c2 - c1,
            "process_wall_s": w2 - w0, "process_cpu_s": c2 - c0,
            "load_before": load0, "load_after": _load()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tag", default="")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    r = run(a.seed)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"diagnose_demo_stage{a.tag}.json").write_text(json.dumps(r, indent=1, default=float))
    lines = ["# `make demo`'s diagnosis stage alone" + (f" ({a.tag.strip('_')})" if a.tag else ""), "",
             f"`python benchmarks/diagnose_demo_stage.py --tag {a.tag}`: concealed "
             f"{r['concealed']}, seed {a.seed}. CPU s = user + system of the process (load-robust).", "",
             "| verdict | findings | baseline fit % | augmented fit % | diagnose wall s | diagnose CPU s "
             "| process wall s | process CPU s | load |",
             "|---|---|---|---|---|---|---|---|---|",
             f"| {r['verdict']} | {', '.join(r['findings'])} | {r['baseline_fit_percent']:.2f} "
             f"| {r['augmented_fit_percent']:.2f} | {r['diagnose_wall_s']:.1f} | {r['diagnose_cpu_s']:.1f} "
             f"| {r['process_wall_s']:.1f} | {r['process_cpu_s']:.1f} "
             f"| {r['load_before']:.1f} → {r['load_after']:.1f} |", "",
             "Parameters: " + json.dumps(r["parameters"], default=float), ""]
    (RESULTS / f"diagnose_demo_stage{a.tag}.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
