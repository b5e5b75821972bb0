"""The thesis' chapter 4–5 control comparison, rebuilt on the virtual printer.

1. An open-loop PRBS experiment on the virtual printer (PA12, realistic effects) gives
   estimation data; models are fitted with `jthermo.identify.fit.fit`: state space of order 4
   (SS4), ARX 6, ARMAX 2 and the grey-box bed. The printer linearised at the window centre
   with its known parameters ("printer grey-box (known)") is added as a reference design model.
2. From each model: the classical designs of `jthermo.control.design` (lambda-tuned diagonal
   PI, decoupled PI, neutral feed-forward, IMC, LQG with integral action), plus the original
   untuned identical PI.
3. Each controller runs against the *virtual printer* (not the model it came from) in the three
   test scenarios, on held-out disturbance seeds: MSE tables like the thesis' Tables 5.1–5.3.
4. Gradient-tuned versions (`jthermo.tune.tune`) of the PI and the LQG, started from their
   classical design on the known model and tuned on other disturbance seeds of the PA12 printer
   and `--ensemble` perturbed copies of it (`plant_ensemble`: capacities, losses, heater gains,
   emissivity, surroundings), with the robust objective (every scenario and plant relative to
   the best classical design there) and the validation guard (seed + VALIDATION) against every
   classical design of the known model.
5. Everything is repeated on a printer with another powder (PA11), which no design or tuning saw.
6. The structured designs on the known model (`--structured`): the firmware relay
   auto-tune PID (`pid_relay`), the full-matrix MIMO PI (`pi_mimo`), and the schedule
   feed-forward around it (`pi_ff`) and around the LQG (`lqg_ff`), the taps from the printer's
   response to each event (`tune.ff_init`); `--tune pi_ff,lqg_ff` tunes their taps (the
   feedback frozen, `tune.ff_init.tuned_fields`).

    python experiments/control_study.py            # writes experiments/results/control_study.md
    python experiments/control_study.py --quick    # small sizes, for a smoke test
    python experiments/control_study.py --resume --models known --tune pi_ff,lqg_ff --steps 20 \
        --ensemble 0                                # add the issue-16 rows to the last results
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np

from jthermo.closedloop import REALISTIC_EFFECTS
from jthermo.control import ScheduleFF, design, rga
from jthermo.data import atomic_write_text
from jthermo.printer import generate, make_printer
from jthermo.tune import (
    HELD_OUT,
    SCENARIOS,
    VALIDATION,
    evaluate,
    plant_ensemble,
    printer_model,
    tune,
)
from jthermo.tune.ff_init import init_schedule_ff, tuned_fields

HERE = Path(__file__).resolve().parent
CLASSICAL = ("pi_untuned", "pi_lambda", "pi_decoupled", "feedforward", "imc", "lqg")
LABELS = {"pi_untuned": "original PI (untuned)", "pi_lambda": "diagonal PI (lambda)",
          "pi_decoupled": "decoupled PI (CB)⁻¹", "feedforward": "feed-forward (neutral)",
          "imc": "IMC", "lqg": "LQG + integral", "gated_pi": "gated PI",
          "pid_relay": "relay auto-tune PID (Z–N)", "pi_mimo": "MIMO PI (full matrices)",
          "pi_ff": "MIMO PI + schedule feed-forward", "lqg_ff": "LQG + schedule feed-forward"}
#: the structured designs, on the known model only (the feed-forward taps come from the
#: printer's response to each event, `init_schedule_ff`)
STRUCTURED = ("pid_relay", "pi_mimo", "pi_ff", "lqg_ff")
#: the fields tuned per family (default: every array leaf); the LQG keeps its design model and
#: operating point and tunes its Riccati weights with the set-point weight of its reference
#: model (the second degree of freedom, for set-point steps)
TUNED_FIELDS = {"lqg": ("q1", "q2", "qi", "qw", "b0", "tau_r")}
#: the designs a tuned controller must beat in every scenario (its validation guard): the LQG
#: every classical design; a diagonal PI, which cannot match the LQG's model-based disturbance
#: rejection with two gains per zone, the other PI designs (original and decoupled)
TUNE_REFERENCES = {"pi_lambda": ("pi_untuned", "pi_decoupled")}
FITS = {"SS4": ("ss", (4,)), "ARX6": ("arx", (6, 6, 1)), "ARMAX2": ("armax", (2, 2, 2, 1)),
        "grey-box (fitted)": ("greybox", ())}


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def fit_models(printer, args):
    try:
        from jthermo.identify.fit import fit
    except Exception as e:
        return {}, {"fitted models": f"jthermo.identify could not be imported ({e})"}
    data = generate(printer, "prbs", args.ident_duration, seed=args.seed + 1)
    models, notes = {}, {}
    for name, (family, orders) in FITS.items():
        if name.split()[0] not in args.models and name not in args.models:
            continue
        t = time.perf_counter()
        try:
            res = fit(data, family, orders, seed=args.seed, n_starts=args.n_starts)
            m = res.model
            rho = float(np.max(np.abs(np.asarray(m.poles()))))
            if not np.isfinite(rho) or rho >= 1.0:
                notes[name] = f"fitted but unstable (spectral radius {rho:.4f}): no design"
                continue
            models[name] = m
            notes[name] = f"fitted in {time.perf_counter() - t:.0f} s, {m.n_states} states"
        except Exception as e:   # report and go on: the study still runs on the other models
            notes[name] = f"fit failed: {type(e).__name__}: {str(e).splitlines()[0][:120]}"
            traceback.print_exc()
        log(f"{name}: {notes[name]}")
    return models, notes


def structured_design(fam, model, printer):
    """`design(fam, model)`, a schedule feed-forward's taps set from `printer`'s response to
    each event (as `tune_report` starts them)."""
    c = design(fam, model)
    return init_schedule_ff(c, printer) if isinstance(c, ScheduleFF) else c


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--zones", type=int, default=4)
    ap.add_argument("--rollouts", type=int, default=None)
    ap.add_argument("--steps", type=int, default=None, help="tuning iterations")
    ap.add_argument("--duration", type=float, default=None, help="scenario length, s")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--models", default="SS4,ARX6,ARMAX2,grey-box,known",
                    help="comma list of SS4, ARX6, ARMAX2, grey-box, known")
    ap.add_argument("--tune", default="pi_lambda,lqg", help="families to tune")
    ap.add_argument("--out", default=str(HERE / "results" / "control_study.md"))
    ap.add_argument("--ensemble", type=int, default=3, help="perturbed printers added in tuning")
    ap.add_argument("--tracking-weight", type=float, default=1.0,
                    help="weight of the tracking MSE in the tuning cost (evaluation keeps 1)")
    ap.add_argument("--resume", action="store_true",
                    help="reuse the results in the JSON next to --out and compute only the rest")
    ap.add_argument("--fitted-pa12-only", action="store_true",
                    help="evaluate designs from fitted models on the PA12 printer only")
    ap.add_argument("--structured", type=int, default=1,
                    help="1: also evaluate the structured designs STRUCTURED on the known model")
    ap.add_argument("--seed-sets", type=int, default=3,
                    help="held-out seed sets (seed + HELD_OUT + j) on which the tuned "
                         "controllers are compared with every classical design of the known model")
    args = ap.parse_args(argv)
    args.models = args.models.split(",")
    R = args.rollouts or (2 if args.quick else 4)
    K = args.steps if args.steps is not None else (10 if args.quick else 150)
    D = args.duration or (200.0 if args.quick else 600.0)
    args.ident_duration = 1200.0 if args.quick else 1800.0
    args.n_starts = 2 if args.quick else 4
    t0 = time.perf_counter()
    args.load_start = os.getloadavg()

    pa12 = make_printer(args.zones, REALISTIC_EFFECTS, powder="PA12", seed=args.seed)
    pa11 = make_printer(args.zones, REALISTIC_EFFECTS, powder="PA11", seed=args.seed)
    held = (args.seed + HELD_OUT,)
    models, notes, rgas, results, tuned = {}, {}, {}, {}, {}

    def write():
        text = report(results, models, notes, rgas, tuned, design_model_name, args, R, K, D,
                      time.perf_counter() - t0)
        atomic_write_text(args.out, text)
        js = {f"{p}|{m}|{c}": v for (p, m, c), v in results.items()}
        js["_tuning"] = tuned
        js["_notes"] = notes
        atomic_write_text(Path(args.out).with_suffix(".json"), json.dumps(js, indent=1))
        return text

    if args.resume and Path(args.out).with_suffix(".json").exists():
        prev = json.loads(Path(args.out).with_suffix(".json").read_text())
        for key, v in prev.items():
            if key.startswith("_"):
                continue
            pn, mn, cn = key.split("|")
            results[(pn, mn, cn)] = v
        for fam, t in prev.get("_tuning", {}).items():
            tuned[fam] = t
        notes.update(prev.get("_notes", {}))
        for fam in args.tune.split(","):
            if ("PA12", "tuned", fam) in results and fam not in tuned:
                tuned[fam] = {}
        log(f"resumed {len(results)} results from {Path(args.out).with_suffix('.json')}")

    def classical(mname, m, printers=("PA12", "PA11")):
        try:
            rgas[mname] = rga(np.asarray(m.dcgain()))
        except Exception as e:
            notes[mname] += f"; RGA failed ({e})"
        for fam in CLASSICAL:
            try:
                c = design(fam, m)
            except Exception as e:
                notes[f"{mname}/{fam}"] = f"design failed: {e}"
                log(notes[f"{mname}/{fam}"])
                continue
            for pname, pl in (("PA12", pa12), ("PA11", pa11)):
                if pname in printers and (pname, mname, fam) not in results:
                    results[(pname, mname, fam)] = evaluate(c, pl, SCENARIOS, held,
                                                            rollouts=R, duration=D)
            log(f"{mname:28s} {fam:14s} PA12 cost {results[('PA12', mname, fam)]['cost']:.4f}")

    def seed_sets(ctrl, dm, fam):
        """MSE per scenario of `ctrl`, its classical start and the best classical design of
        the known model, on each held-out seed set (the first is the main tables' seed)."""
        out = {}
        for pname, pl in (("PA12", pa12), ("PA11", pa11)):
            for j in range(args.seed_sets):
                s = args.seed + HELD_OUT + j
                ev = {f: results[(pname, design_model_name, f)] if j == 0 else
                      evaluate(design(f, dm), pl, SCENARIOS, (s,), rollouts=R, duration=D)
                      for f in CLASSICAL}
                if fam not in ev:       # a structured start (STRUCTURED): its own row
                    ev[fam] = results[(pname, design_model_name, fam)] if j == 0 else evaluate(
                        structured_design(fam, dm, pa12), pl, SCENARIOS, (s,), rollouts=R,
                        duration=D)
                ev["tuned"] = results[(pname, "tuned", fam)] if j == 0 else \
                    evaluate(ctrl, pl, SCENARIOS, (s,), rollouts=R, duration=D)
                row = {}
                for k in SCENARIOS:
                    best = min(CLASSICAL, key=lambda f: ev[f]["scenarios"][k]["mse"])
                    row[k] = {"tuned": ev["tuned"]["scenarios"][k]["mse"],
                              "start": ev[fam]["scenarios"][k]["mse"],
                              "best_classical": ev[best]["scenarios"][k]["mse"],
                              "best_family": best}
                row["cost"] = {"tuned": ev["tuned"]["cost"], "pi_lambda": ev["pi_lambda"]["cost"]}
                out[f"{pname}|{s}"] = row
                log(f"seed set {pname} {s}: " + ", ".join(
                    f"{k} {row[k]['tuned']:.4f} vs {row[k]['best_classical']:.4f}"
                    for k in SCENARIOS))
        return out

    # 1. the known grey-box first: classical designs and the gradient-tuned versions
    design_model_name = "printer grey-box (known)"
    dm = printer_model(pa12)
    models[design_model_name] = dm
    notes[design_model_name] = "the printer's own parameters, linearised at the window centre"
    classical(design_model_name, dm)
    for fam in STRUCTURED if args.structured else ():
        c = structured_design(fam, dm, pa12)
        for pname, pl in (("PA12", pa12), ("PA11", pa11)):
            if (pname, design_model_name, fam) not in results:
                results[(pname, design_model_name, fam)] = evaluate(c, pl, SCENARIOS, held,
                                                                    rollouts=R, duration=D)
        log(f"{design_model_name:28s} {fam:14s} PA12 cost "
            f"{results[('PA12', design_model_name, fam)]['cost']:.4f}")
    write()
    for fam in args.tune.split(","):
        if ("PA12", "tuned", fam) in results:
            continue
        start = structured_design(fam, dm, pa12)
        refs = [design(f, dm) for f in TUNE_REFERENCES.get(fam, CLASSICAL) if f != fam]
        t = time.perf_counter()
        res = tune(start, pa12, plants=plant_ensemble(pa12, args.ensemble, seed=args.seed),
                   rollouts=R, steps=K, lr=0.05, seed=args.seed, duration=D,
                   weights={"tracking": args.tracking_weight}, references=refs,
                   params=TUNED_FIELDS.get(fam, tuned_fields(start)),
                   progress=lambda i, v: log(f"tune {fam} {i} {v:.4f}") if i % 25 == 0 else None)
        g = res.guard or {}
        tuned[fam] = {"start_cost": res.start_cost, "tuned_cost": res.tuned_cost,
                      "iterations": len(res.history), "seconds": time.perf_counter() - t,
                      "guard": {k: v for k, v in g.items() if k in ("chosen", "margin", "passed")},
                      "params": {k: np.asarray(v).tolist() for k, v in vars(res.controller).items()
                                 if k in ("kp", "ti", "q1", "q2", "qi", "qw", "b0", "tau_r")}}
        for pname, pl in (("PA12", pa12), ("PA11", pa11)):
            results[(pname, "tuned", fam)] = evaluate(res.controller, pl, SCENARIOS, held,
                                                      rollouts=R, duration=D)
        log(f"tuned {fam}: train {res.start_cost:.4f} -> {res.tuned_cost:.4f}; held-out PA12 "
            f"{results[('PA12', 'tuned', fam)]['cost']:.4f} PA11 "
            f"{results[('PA11', 'tuned', fam)]['cost']:.4f}")
        tuned[fam]["seed_sets"] = seed_sets(res.controller, dm, fam)
        write()
    # 2. models fitted on virtual-printer data, one at a time (the report grows as they finish)
    fitted, fnotes = fit_models(pa12, args)
    notes.update(fnotes)
    for mname, m in fitted.items():
        models[mname] = m
        classical(mname, m, printers=("PA12",) if args.fitted_pa12_only else ("PA12", "PA11"))
        write()
    text = write()
    print(text)
    return 0


def report(results, models, notes, rgas, tuned, dname, args, R, K, D, seconds):
    L = ["# Control study: the thesis' chapter 4–5 comparison on the virtual printer", "",
         f"Command: `python experiments/control_study.py {' '.join(sys.argv[1:])}`. "
         f"{args.zones}-zone virtual printer with {', '.join(REALISTIC_EFFECTS)}; scenarios "
         f"{D:.0f} s each, {R} held-out disturbance rollouts (seed {args.seed + HELD_OUT}) per "
         f"scenario; tuning: {K} Adam iterations on {R} rollouts per scenario from seed "
         f"{args.seed} on the PA12 printer and {args.ensemble} perturbed copies (`plant_ensemble`), "
         f"robust objective relative to the best reference design per scenario and plant "
         f"(LQG: every classical design; PI: the original and decoupled PI), "
         f"validation guard on seed {args.seed + VALIDATION}; tracking weight "
         f"{args.tracking_weight:g} in the tuning cost. PA11 is never seen in design or tuning. "
         f"Total run time {seconds / 60:.1f} min; `os.getloadavg()` (1/5/15 min) "
         f"{'/'.join(f'{x:.2f}' for x in args.load_start)} at the start, "
         f"{'/'.join(f'{x:.2f}' for x in os.getloadavg())} at the end.", "",
         "Cost = `closedloop.cost` (tracking MSE + neighbour non-uniformity + input variation + "
         "smooth time outside ±1 °C), mean over the three scenarios. MSE = measured output vs "
         "set point, °C² (the thesis' tables).", "", "## Models", ""]
    for m, n in notes.items():
        L.append(f"- **{m}**: {n}")
    L += [""]
    for m, g in rgas.items():
        L.append(f"RGA diagonal of {m}: {np.round(np.diag(g), 2).tolist()}")
    L += [""]
    for pname in ("PA12", "PA11"):
        title = "design powder (PA12)" if pname == "PA12" else "changed powder (PA11, unseen)"
        L += [f"## Printer with {title}", ""]
        for k, tname in zip(SCENARIOS, ("Reference tracking (Table 5.1)",
                                        "Powder disturbance suppression (Table 5.2)",
                                        "Print disturbance suppression (Table 5.3)")):
            L += [f"### {tname}: MSE, °C²", ""]
            mnames = list(models) + sorted({m for (_, m, _) in results
                                            if m not in models and m != "tuned"})
            L.append("| controller | " + " | ".join(mnames) + " |")
            L.append("|---|" + "---|" * len(mnames))
            for fam in CLASSICAL + STRUCTURED:
                if not any((pname, m, fam) in results for m in mnames):
                    continue
                row = [f"{results[(pname, m, fam)]['scenarios'][k]['mse']:.4f}"
                       if (pname, m, fam) in results else "—" for m in mnames]
                L.append(f"| {LABELS[fam]} | " + " | ".join(row) + " |")
            for fam in tuned:
                v = results[(pname, "tuned", fam)]["scenarios"][k]["mse"]
                L.append(f"| **{LABELS[fam]}, gradient-tuned** (from {dname}) | {v:.4f} | "
                         + " | ".join("" for _ in mnames[1:]) + " |")
            L.append("")
        # summary against every classical design
        L += [f"### Summary on {pname}: mean cost over the three scenarios", "",
              "| controller | model | cost | tracking MSE | powder MSE | print MSE |",
              "|---|---|---|---|---|---|"]
        rows = sorted(((v["cost"], m, c, v) for (p, m, c), v in results.items() if p == pname),
                      key=lambda r: r[0])
        for cst, m, c, v in rows:
            s = v["scenarios"]
            L.append(f"| {LABELS[c]}{' (tuned)' if m == 'tuned' else ''} | {m} | {cst:.4f} | "
                     f"{s['tracking']['mse']:.4f} | {s['powder']['mse']:.4f} | "
                     f"{s['print']['mse']:.4f} |")
        L.append("")
        lam = results.get((pname, dname, "pi_lambda"))
        for fam in tuned:
            tv = results[(pname, "tuned", fam)]
            classical = [(m, c, v) for (p, m, c), v in results.items() if p == pname and m != "tuned"]
            beats = {k: all(tv["scenarios"][k]["mse"] < v["scenarios"][k]["mse"]
                            for _, _, v in classical) for k in SCENARIOS}
            beats_cost = {k: all(tv["scenarios"][k]["cost"] < v["scenarios"][k]["cost"]
                                 for _, _, v in classical) for k in SCENARIOS}
            imp = 100 * (1 - tv["cost"] / lam["cost"]) if lam else float("nan")
            L.append(f"- tuned {LABELS[fam]}: cost {tv['cost']:.4f} vs lambda PI ({dname}) "
                     f"{lam['cost'] if lam else float('nan'):.4f}: **{imp:.1f} % lower**; beats every "
                     f"classical design on MSE in " + ", ".join(f"{k}: {'yes' if b else 'no'}"
                                                            for k, b in beats.items())
                     + "; on cost in " + ", ".join(f"{k}: {'yes' if b else 'no'}"
                                                   for k, b in beats_cost.items()))
        L.append("")
    L += ["## Tuning", ""]
    for fam, t in tuned.items():
        if "start_cost" not in t:
            L.append(f"- {LABELS[fam]}: tuned in an earlier run of this script (`--resume`); "
                     "training summary not kept.")
            continue
        L.append(f"- {LABELS[fam]}: training cost (relative to the start in each scenario) "
                 f"{t['start_cost']:.4f} → {t['tuned_cost']:.4f} in {t['iterations']} "
                 f"iterations, {t['seconds']:.0f} s (includes compilation); validation guard "
                 f"{json.dumps(t.get('guard'))}; tuned parameters "
                 f"{json.dumps({k: np.round(v, 4).tolist() for k, v in t['params'].items()})}.")
    L.append("")
    for fam, t in tuned.items():
        if not t.get("seed_sets"):
            continue
        L += [f"### {LABELS[fam]}, gradient-tuned, on {args.seed_sets} held-out seed sets", "",
              (f"MSE (°C²) of the tuned controller, of its classical start and of the best "
               f"classical design of the known model, {R} rollouts per seed set and scenario; "
               f"margin = 100·(1 − tuned/best classical)."), "",
              ("| printer | seed | scenario | tuned | classical start | best classical (family) "
               "| margin vs best, % | cost: tuned vs lambda PI, % lower |"),
              "|---|---|---|---|---|---|---|---|"]
        for key, row in t["seed_sets"].items():
            pname, s = key.split("|")
            c = row["cost"]
            for k in SCENARIOS:
                v = row[k]
                L.append(f"| {pname} | {s} | {k} | {v['tuned']:.4f} | {v['start']:.4f} | "
                         f"{v['best_classical']:.4f} ({v['best_family']}) | "
                         f"{100 * (1 - v['tuned'] / v['best_classical']):+.2f} | "
                         f"{100 * (1 - c['tuned'] / c['pi_lambda']):.1f} |")
        L.append("")
    return "\n".join(L)


if __name__ == "__main__":
    sys.exit(main())
