"""Physical plausibility of fits to real heater recordings: which model structures
step the wrong way (`validate.plausibility`), and what that costs in validation fit.

The Klipper hot-end's order-2 state-space fits of `experiments/own_plant.py` fall by several °C
after the heater switches on. Per record pair (estimation -> validation) and candidate (family,
orders; `None`: chosen by `fit` as `jthermo fit` does without `--orders`): validation fit %,
the plausibility findings (`validate.plausibility.check_fit`: the estimation record's noise level
and input span) and the CPU time of that check, the
largest wrong-way move of each step response (°C, for a full 0 -> 1 heater step) and when.

Usage:  python experiments/plausibility_real.py [--quick]
Writes `experiments/results/plausibility_real.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from jthermo.data import IOData, load_csv  # noqa: E402
from jthermo.errors import JThermoError  # noqa: E402
from jthermo.identify import fit  # noqa: E402
from jthermo.validate import compare  # noqa: E402
from jthermo.validate.plausibility import check_fit  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
OUT = ROOT / "experiments" / "results"
KLIPPER = REAL / "klipper_onionheater"
TCLAB = REAL / "tclab_cace2020"
#: (label, estimation record, validation record)
PAIRS = [
    ("hotend heattest_200 -> sample_trace", KLIPPER / "heattest_200", KLIPPER / "sample_trace"),
    ("hotend sample_trace -> heattest_200", KLIPPER / "sample_trace", KLIPPER / "heattest_200"),
    ("tclab id_2heaters -> val_2heaters", TCLAB / "id_2heaters", TCLAB / "val_2heaters"),
]
#: (family, orders or None); the first is own_plant.py's hot-end model
CANDIDATES = [("ss", (2,)), ("ss", None), ("ss", (1,)), ("ss", (3,)), ("oe", None),
              ("arx", None)]
QUICK = [("ss", (2,)), ("ss", (1,)), ("oe", None)]


def load(path: Path) -> IOData:
    """Heater and sensor columns only (the hot-end's fan command is a reconstruction)."""
    d = load_csv(path / "data.csv")
    return IOData(u=d.u, y=d.y, w=d.u[:, :0], ts=d.ts, input_names=d.input_names,
                  output_names=d.output_names, signal_names=())


def one(est: IOData, val: IOData, family: str, orders) -> dict:
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res = fit(est, family, orders)
    except JThermoError as exc:
        return {"family": family, "orders": orders, "error": str(exc)}
    secs, cpu = time.perf_counter() - t0, time.process_time() - c0
    env = res.envelope
    c1 = time.process_time()
    chk = check_fit(res.model, env, input_names=est.input_names, output_names=est.output_names)
    check_cpu = time.process_time() - c1
    return {"family": family, "asked_orders": orders, "orders": dict(res.orders or {}),
            "fit_percent": [float(v) for v in compare(res.model, val)["fit_percent"]],
            "warnings": chk["warnings"],
            "wrong_way_C": [p["wrong_way_C"] for p in chk["pairs"]],
            "wrong_way_at_s": [p["wrong_way_at_s"] for p in chk["pairs"]],
            "dc_gain": [p["dc_gain"] for p in chk["pairs"]],
            "noise_std": list(env.noise_std) if env else None,
            "window_s": chk["window_s"], "fit_wall_s": secs, "fit_cpu_s": cpu,
            "check_cpu_s": check_cpu}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="hot-end pairs, three candidates")
    args = ap.parse_args(argv)
    pairs = PAIRS[:2] if args.quick else PAIRS
    cands = QUICK if args.quick else CANDIDATES
    load1 = os.getloadavg()[0]
    rows = []
    for label, e, v in pairs:
        est, val = load(e), load(v)
        for family, orders in cands:
            r = {"pair": label, **one(est, val, family, orders)}
            rows.append(r)
            print(json.dumps({k: r.get(k) for k in ("pair", "family", "orders", "fit_percent",
                                                    "wrong_way_C", "fit_cpu_s")}), flush=True)
    load2 = os.getloadavg()[0]
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "plausibility_real.json").write_text(json.dumps(
        {"rows": rows, "load_1min": [load1, load2], "peak_rss_mb": rss}, indent=1))
    lines = ["# Plausibility of fits to real heater recordings", "",
             f"`python experiments/plausibility_real.py{' --quick' if args.quick else ''}`; "
             f"1-minute load {load1:.1f} at the start, {load2:.1f} at the end (shared machine: wall "
             "times inflated; CPU s is the process's, load-robust). Wrong-way move: the largest "
             "excursion of the step response (0 -> 1 heater step) against its final direction, "
             "°C per output, with its time; flagged when above max(3 sigma, 1 % of the response).",
             "", "| estimation -> validation | family | orders | validation fit % | wrong-way °C "
             "(at s) | flagged | fit wall s | fit CPU s | check CPU s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['pair']} | {r['family']} | {r['orders']} | error: {r['error']} |"
                         " | | | | |")
            continue
        ww = ", ".join(f"{w:.3g} ({t:.3g})" for w, t in zip(r["wrong_way_C"], r["wrong_way_at_s"]))
        orders = ",".join(f"{k}={v}" for k, v in r["orders"].items())
        asked = "" if r["asked_orders"] is not None else " (auto)"
        lines.append(f"| {r['pair']} | {r['family']} | {orders}{asked} | "
                     f"{', '.join(f'{f:.2f}' for f in r['fit_percent'])} | {ww} | "
                     f"{len(r['warnings'])} | {r['fit_wall_s']:.1f} | {r['fit_cpu_s']:.1f} | "
                     f"{r['check_cpu_s']:.3f} |")
    (OUT / "plausibility_real.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
