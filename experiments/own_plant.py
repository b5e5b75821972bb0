"""Tune a user's own device from its recordings: TCLab with two heaters and a Klipper
3D-printer hot-end.

Per device a model is fitted to one record (the design model) and another to a different
record (the evaluation plant, never tuned on). From the design model: every classical design
of `tune.report.CLASSICAL` (untuned PI, lambda PI, decoupled PI, feed-forward, IMC, LQG and
`pid_relay`, the firmware's relay auto-tune + Ziegler–Nichols) at the set point's
equilibrium, and PI and PID tuned with jthermo's defaults (`tune.tune_own_plant`, starting
from the lambda PI and from `pid_relay`; a PID also tuned on the start-up step is reported
beside them, not for the acceptance). All are run on the evaluation plant in the model's
own scenarios (set-point changes around the operating point, load, start-up; held-out seed). Reported:
set-point-change MSE on the evaluation plant, the start-up step's overshoot, and the acceptance of
the targets (tuned MSE ≥ 20 % below the best classical; hot-end overshoot ≤ 2 °C).

Usage:  python experiments/own_plant.py [--steps N] [--rollouts N] [--devices tclab,hotend]
Writes `experiments/results/own_plant.md` and `own_plant.json`; the closed-loop figures go to
`runs/own_plant/` (untracked).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from jthermo import plots  # noqa: E402
from jthermo.closedloop import model_scenario, simulate  # noqa: E402
from jthermo.data import load_csv  # noqa: E402
from jthermo.errors import ControlError  # noqa: E402
from jthermo.identify import fit  # noqa: E402
from jthermo.tune import tune_own_plant  # noqa: E402
from jthermo.tune.own import MAX_SATURATED_CHANGES, OWN_SCENARIOS, PID_TYPE  # noqa: E402
from jthermo.validate import compare  # noqa: E402

REAL = ROOT.parent / "shared" / "data" / "real"
OUT = ROOT / "experiments" / "results"

#: device: design record, evaluation record, model family and orders, set point (°C)
DEVICES = {
    "tclab": dict(design=REAL / "tclab_cace2020" / "id_2heaters" / "data.csv",
                  evaluation=REAL / "tclab_cace2020" / "val_2heaters" / "data.csv",
                  family="ss", orders=(4,), setpoint=(55.0, 45.0)),
    "hotend": dict(design=REAL / "klipper_onionheater" / "heattest_200" / "data.csv",
                   evaluation=REAL / "klipper_onionheater" / "sample_trace" / "data.csv",
                   family="ss", orders=(2,), setpoint=(200.0,)),
}
#: label: (start family, extra scenarios tuned on besides the defaults)
TUNED = {"tuned PI": ("pi_lambda", ()), "tuned PID": ("pid_relay", ()),
         "tuned PID (+start-up)": ("pid_relay", ("preheat",))}


def load(path):
    """The record's heater and sensor columns (the hot-end's fan command is a reconstruction,
    mostly 0; the closed loops here run without it)."""
    d = load_csv(path)
    if d.w.shape[1]:
        from jthermo.data import IOData
        d = IOData(u=d.u, y=d.y, w=np.zeros((d.n_samples, 0)), ts=d.ts,
                   input_names=d.input_names, output_names=d.output_names, signal_names=())
    return d


def device_study(name, spec, steps, rollouts, seed):
    t0 = time.perf_counter()
    est, ev = load(spec["design"]), load(spec["evaluation"])
    fd, fe = fit(est, spec["family"], spec["orders"]), fit(ev, spec["family"], spec["orders"])
    fits = {"design_on_evaluation_record": compare(fd.model, ev)["fit_percent"],
            "evaluation_on_design_record": compare(fe.model, est)["fit_percent"]}
    runs, failed = {}, {}
    for label, (fam, extra) in TUNED.items():
        try:
            runs[label] = tune_own_plant(fam, fd.model, envelope=fd.envelope,
                                         setpoint=spec["setpoint"], validation_plant=fe.model,
                                         steps=steps, rollouts=rollouts, seed=seed,
                                         kinds=(*OWN_SCENARIOS, *extra))
        except ControlError as exc:          # the tuned loop failed its own judge: say so
            failed[label] = str(exc)
    if not runs:
        return {"device": name, "failed": failed, "fits": fits}
    first = next(iter(runs.values()))
    val = first["validation"]["scenarios"]
    table = {f: row(val[f]) for f in val if f not in ("start", "tuned")}
    for label, res in runs.items():
        table[label] = row(res["validation"]["scenarios"]["tuned"])
    classical = [f for f in table if f not in TUNED]
    best = min(classical, key=lambda f: table[f]["tracking_mse"])
    defaults = [f for f in runs if not TUNED[f][1]] or list(runs)   # jthermo's defaults
    tuned = min(defaults, key=lambda f: table[f]["tracking_mse"])
    gain = 100.0 * (1.0 - table[tuned]["tracking_mse"] / table[best]["tracking_mse"])
    pid_type = [f for f in classical if f in PID_TYPE]
    best_pid = min(pid_type, key=lambda f: table[f]["tracking_mse"]) if pid_type else None
    gain_pid = None if best_pid is None else 100.0 * (
        1.0 - table[tuned]["tracking_mse"] / table[best_pid]["tracking_mse"])
    ctrls = {label: res["tuned"] for label, res in runs.items()}
    sc = model_scenario("tracking", fe.model, first["duration"], seed, envelope=fd.envelope,
                        setpoint=first["setpoints"])
    change = (np.max(np.asarray(sc.r), axis=0) - np.asarray(first["setpoints"])).tolist()
    v = first["validation"]
    figure(name, fe.model, fd.envelope, first["setpoints"], first["duration"],
           {**ctrls, best: classical_controller(fd.model, best, first["setpoints"])}, seed)
    return {"device": name, "design": str(spec["design"].relative_to(REAL)),
            "evaluation": str(spec["evaluation"].relative_to(REAL)), "ts": est.ts,
            "family": spec["family"], "orders": list(spec["orders"]), "fits": fits,
            "setpoints": first["setpoints"], "duration": first["duration"], "table": table,
            "best_classical": best, "best_tuned": tuned,
            "tracking_improvement_percent": gain, "failed": failed,
            "accept_20_percent": bool(gain >= 20.0),
            "startup_overshoot_C": table[tuned]["startup_overshoot_C"],
            "accept_overshoot_2C": bool(table[tuned]["startup_overshoot_C"] <= 2.0),
            "change_C": change,
            **{k: v[k] for k in ("startup_floor_mse", "tracking_floor_mse", "noise_mse",
                                 "tracking_bound_mse")},
            "bang_bang": sorted(f for f in table
                                if table[f]["tracking_saturated"] > MAX_SATURATED_CHANGES),
            "best_pid_type": best_pid, "improvement_vs_best_pid_type_percent": gain_pid,
            "weights": first["weights"], "term_scales": {k: r["term_scales"] for k, r in runs.items()},
            "tuning": {label: {"moved": res["moved"], "guard": res["guard"],
                               "verdict": res["validation"]["verdict"],
                               "guard_candidates": res["guard_candidates"],
                               "train_start_cost": res["train_start_cost"],
                               "train_tuned_cost": res["train_tuned_cost"],
                               "history_min": min(res["history"]) if res["history"] else None}
                       for label, res in runs.items()},
            "tuned_gains": {label: {k: np.asarray(getattr(c, k)).tolist()
                                    for k in ("kp", "ti", "td", "b") if hasattr(c, k)}
                            for label, c in ctrls.items()},
            "seconds": time.perf_counter() - t0}


def row(m):
    """The figures of one controller on the evaluation plant: set-point changes (`tracking`),
    load, and the start-up step (`preheat`) with its overshoot."""
    return {"tracking_mse": m["tracking"]["mse"], "tracking_overshoot_C": m["tracking"]["overshoot_C"],
            "tracking_saturated": m["tracking"]["saturated_fraction"],
            "input_variation": m["tracking"]["input_variation"],
            "load_mse": m["load"]["mse"], "startup_mse": m["preheat"]["mse"],
            "startup_overshoot_C": m["preheat"]["overshoot_C"],
            "startup_settling_s": m["preheat"]["settling_time_s"], "cost": m["cost"]}


def classical_controller(model, family, setpoint):
    from jthermo.control import design
    return design(family, model, setpoint=setpoint)


def figure(name, plant, env, setpoint, duration, ctrls, seed):
    sc = model_scenario("tracking", plant, duration, seed + 1000, envelope=env, setpoint=setpoint)
    t = np.arange(sc.r.shape[0]) * plant.ts
    for label, c in ctrls.items():
        tr = simulate(plant, c, sc)
        slug = label.replace(" ", "_")
        (ROOT / "runs" / "own_plant").mkdir(parents=True, exist_ok=True)
        plots.plot_closed_loop(t, np.asarray(tr.y), np.asarray(tr.u), np.asarray(tr.r),
                               path=ROOT / "runs" / "own_plant" / f"{name}_{slug}.png")


def markdown(results, args) -> str:
    lines = ["# Tuning your own device: TCLab (2 heaters) and a Klipper hot-end", "",
             f"`python experiments/own_plant.py --steps {args.steps} --rollouts {args.rollouts}"
             f" --seed {args.seed}`. Design model fitted to one record, every "
             "controller designed/tuned on it and run on a model fitted to another record "
             "(held-out seed). Set-point changes: settled at the set point, +δ at 10 % of the "
             "run, -δ at 55 % (closedloop.model_scenario `tracking`), δ at most 10 % of the "
             "recorded range, scaled down until a first-order loop ten times faster than the "
             "plant follows both changes without an input at a limit "
             "(`models.envelope.change_scale`); load: input-referred heat sink of 25 % of the "
             "recorded input std; start-up: heaters off to the set point (`preheat`), judged "
             "on its own. A loop at an input limit more than "
             f"{100 * MAX_SATURATED_CHANGES:.0f} % of the set-point changes is marked bang-bang "
             "(a tuned one is refused). Figures: `own_plant_<device>_<controller>.png` "
             "(set-point changes on the evaluation plant).", ""]
    for r in results:
        if "table" not in r:
            lines += [f"## {r['device']}", "", f"- every tuning failed: {r['failed']}", ""]
            continue
        lines += [f"## {r['device']}", "",
                  f"- design record `{r['design']}`, evaluation record `{r['evaluation']}`, "
                  f"Ts {r['ts']:g} s, {r['family']} orders {r['orders']}; fits (%): design "
                  f"model on the evaluation record {np.round(r['fits']['design_on_evaluation_record'], 1).tolist()}, "
                  f"evaluation model on the design record {np.round(r['fits']['evaluation_on_design_record'], 1).tolist()}",
                  f"- set points {np.round(r['setpoints'], 2).tolist()} °C, set-point changes "
                  f"δ = {np.round(r['change_C'], 3).tolist()} °C, scenarios of "
                  f"{r['duration']:g} s", "",
                  "| controller | set-point changes MSE (°C²) | overshoot (°C) | saturated | mean abs Δu | load MSE (°C²) | start-up MSE (°C²) | start-up overshoot (°C) | start-up settling (s) | cost |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for f, m in sorted(r["table"].items(), key=lambda kv: kv[1]["tracking_mse"]):
            tag = " (bang-bang)" if f in r["bang_bang"] else ""
            lines.append(f"| {f}{tag} | {m['tracking_mse']:.4g} | {m['tracking_overshoot_C']:.3g} | "
                         f"{m['tracking_saturated']:.2f} | {m['input_variation']:.3g} | "
                         f"{m['load_mse']:.4g} | {m['startup_mse']:.4g} | "
                         f"{m['startup_overshoot_C']:.3g} | {m['startup_settling_s']:.4g} | "
                         f"{m['cost']:.4g} |")
        lines += ["", f"- best classical (set-point changes MSE): **{r['best_classical']}**; best "
                  f"tuned: **{r['best_tuned']}**, {r['tracking_improvement_percent']:.1f} % below "
                  f"it (acceptance ≥ 20 %: {'met' if r['accept_20_percent'] else 'NOT met'}); its "
                  f"start-up overshoot {r['startup_overshoot_C']:.3g} °C (≤ 2 °C: "
                  f"{'met' if r['accept_overshoot_2C'] else 'NOT met'})", ""]
        if r.get("best_pid_type"):
            lines += [f"- against the best PI/PID-type classical design ({r['best_pid_type']}): "
                      f"{r['improvement_vs_best_pid_type_percent']:.1f} % below it", ""]
        if r.get("tracking_floor_mse") is not None:
            lines += [(f"- set-point-change MSE floor estimate on the evaluation plant (after "
                       f"each change, every heater at its limit from steady state until the new "
                       f"set point; `tune.own.tracking_floor(kind='tracking')`; an estimate, not "
                       f"a strict bound: a change need not start from steady state): "
                       f"{r['tracking_floor_mse']:.4g} °C², "
                       f"{100 * (1 - r['tracking_floor_mse'] / r['table'][r['best_classical']]['tracking_mse']):.1f}"
                       f" % below {r['best_classical']}"), ""]
        if r.get("tracking_bound_mse") is not None:
            best_mse = r["table"][r["best_classical"]]["tracking_mse"]
            lines += [(f"- measurement noise (the recording's, in every measured MSE): "
                       f"{r['noise_mse']:.4g} °C²; floor + noise = {r['tracking_bound_mse']:.4g}"
                       f" °C²: no controller within the input limits is more than "
                       f"{100 * (1 - r['tracking_bound_mse'] / best_mse):.1f} % below "
                       f"{r['best_classical']} on these set-point changes"), ""]
        if r.get("startup_floor_mse") is not None:
            lines += [(f"- start-up MSE floor on the evaluation plant (every heater at full "
                       f"power until the set point, zero error after; `tune.own.tracking_floor`):"
                       f" {r['startup_floor_mse']:.4g} °C²"), ""]
        lines += [f"- cost weights (each relative to its term's value for the start): "
                  f"{r['weights']}", ""]
        for label, t in r.get("tuning", {}).items():
            g = t["guard"]
            worst = min((c["mse_ratio_worst"] for c in (t["guard_candidates"] or [])
                         if c["iteration"] != 0), default=float("nan"))
            lines.append(f"- {label}: training objective {t['train_start_cost']:.3g} -> best "
                         f"{t['history_min']:.3g}; guard {'passed' if g.get('passed') else 'FAILED'}"
                         f" (chosen iteration {g.get('chosen')}, margin {g.get('margin')}; best "
                         f"worst-item mse ratio of a moved iterate {worst:.4f}); gains "
                         f"{'moved' if t['moved'] else 'NOT moved (the start kept)'}: "
                         f"{r['tuned_gains'][label]}")
        lines += [""] + [f"- {label} failed: {why}" for label, why in r["failed"].items()] + [""]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--rollouts", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--devices", default="tclab,hotend")
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    results = []
    for name in args.devices.split(","):
        results.append(device_study(name, DEVICES[name], args.steps, args.rollouts, args.seed))
        print(json.dumps({k: v for k, v in results[-1].items() if k != "table"}, default=str))
    (OUT / "own_plant.json").write_text(json.dumps(results, indent=1, default=float))
    (OUT / "own_plant.md").write_text(markdown(results, args))


if __name__ == "__main__":
    main()
