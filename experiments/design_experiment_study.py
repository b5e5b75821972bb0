"""Designed experiments against PRBS on the virtual printer.

For each case the printer hides one mechanism of a rival pair that PRBS records tend to leave
tied (heater lag / input delay, a slow chamber body / an unmeasured surroundings drift,
radiation / lamp nonlinearity). A PRBS estimation and validation record are diagnosed; the
input that separates the two explanations (`jthermo.diagnose.experiment.design_experiment`, the
top finding and its rivals; with no rival the runner-up and the baseline) is run
on the true printer, and the diagnosis is repeated with that record as the validation record
(the models are fitted on the same estimation record), as the estimation record (validated on
the PRBS validation record), and as both (the designed input run twice, new noise and
surroundings each time). The comparison is a PRBS record of the same length, actuator limits and
minimum switching time, run on the same printer. The designed record is as long as the
validation record, or `DESIGN_S` for the slow cases (a body of 40 min shows in no 15-min
record).

    .venv/bin/python experiments/design_experiment_study.py [--cases a,b] [--seeds 0,1,2]
        [--criterion nuisance|nuisance_drift|span] [--duration case|val|est] [--steps 150]
        [--out experiments/results]

Writes `experiments/results/design_experiment{T}.md`, `.json` and `design_experiment{T}.png`.
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

import numpy as np

from jthermo import printer as P
from jthermo.data import atomic_write_text, from_arrays
from jthermo.diagnose import diagnose, to_json
from jthermo.diagnose.experiment import design_experiment
from jthermo.diagnose.experiment import to_json as design_json
from jthermo.inputs import prbs

ROOT = Path(__file__).resolve().parents[1]

#: name: (truth, printer effects, zones, estimation s, validation s, PRBS levels, PRBS hold s,
#: noise °C, measured surroundings)
CASES = {
    "delay": ("input_delay", {"input_delay": {"delay_s": 2}}, 1, 1200, 600, (0.35, 0.65), (40, 120), 0.15, True),
    "lag": ("heater_lag", {"heater_lag": {"time_constant_s": 2.0}}, 1, 1200, 600, (0.35, 0.65), (40, 120),
            0.15, True),
    "body": ("heat_accumulation", {"heat_accumulation": {"time_constant_s": 2400.0, "share": 0.4}}, 1,
             1800, 900, (0.35, 0.65), (100, 400), 0.1, False),
    "drift": ("ambient_variation", {"ambient_variation": {"amplitude_C": 1.0, "period_s": 3600.0,
                                                          "walk_C": 0.01}}, 1, 1800, 900, (0.35, 0.65),
              (100, 400), 0.1, False),
    "radiation": ("radiative_loss", {"radiative_loss": {}}, 1, 1200, 600, (0.2, 0.8), (20, 60), 0.05, True),
    "nonlinearity": ("input_nonlinearity", {"input_nonlinearity": {"exponent": 1.15}}, 1, 1200, 600,
                     (0.2, 0.8), (20, 60), 0.05, True),
}

#: designed record's length (s) of the slow cases under `--duration case` (others: the validation record's)
DESIGN_S = {"body": 3600, "drift": 3600}
#: how each new record is used: (key, estimation, validation) with "new" the new record, "new2" its rerun
ARMS = (("as_validation", "est", "new"), ("as_estimation", "new", "val"), ("twice", "new", "new2"))


def run_printer(pr, u, seed, noise, u_rest, measured):
    """A record of the printer on input `u (T, nu)` from its steady state at `u_rest`, with
    white + AR(1) sensor noise of std `noise` each (°C)."""
    T = u.shape[0]
    d = P.disturbances(pr, T, jax.random.key(seed))
    x0 = P.steady_state(pr, u_rest)
    y, _ = P.simulate_open_loop(pr, u, d, x0)
    rng = np.random.default_rng(seed)
    y = np.asarray(y) + rng.normal(size=np.shape(y)) * noise
    c = np.zeros_like(y)
    w = rng.normal(size=y.shape) * noise * np.sqrt(1 - 0.8 ** 2)
    for k in range(1, T):
        c[k] = 0.8 * c[k - 1] + w[k]
    y = y + c
    if measured:
        return from_arrays(u, y, pr.ts, np.asarray(d.ambient)[:, None], signal_names=["ambient"])
    return from_arrays(u, y, pr.ts)


def summary(res, truth):
    f = res["findings"]
    row = next((c for c in res["candidates"] if c["mechanism"] == truth), None)
    tests = None if row is None else {k: row[k] for k in ("validation_z", "validation_z_critical", "estimation_lr",
                                                          "estimation_lr_critical", "significant")}
    return {"top": f[0]["mechanism"] if f else None, "rivals": f[0]["rivals"] if f else [],
            "named": [x["mechanism"] for x in f], "confidence": f[0]["confidence"] if f else None,
            "fit": res["augmented"]["mean_fit_percent"], "truth_tests": tests}


def run_case(name, steps, seed=0, criterion="nuisance", duration="val"):
    """One case on one seed: the printer (seed), the PRBS records (10 seed + 1), their noise
    (10 seed + 2), the noise of the new records (10 seed + 3, the same draw in both arms)."""
    truth, eff, zones, t_est, t_val, levels, hold, noise, measured = CASES[name]
    pr = P.make_printer(zones, effects=eff, seed=seed)
    u_rest = 0.5 * (levels[0] + levels[1])
    u = np.asarray(prbs(10 * seed + 1, t_est + t_val, pr.n_inputs, levels=levels, hold=hold), float)
    rec = run_printer(pr, u, 10 * seed + 2, noise, u_rest, measured)
    est = rec.replace(u=rec.u[:t_est], y=rec.y[:t_est], w=rec.w[:t_est])
    val = rec.replace(u=rec.u[t_est:], y=rec.y[t_est:], w=rec.w[t_est:], t0=float(t_est))
    t0 = time.perf_counter()
    res = diagnose(est, val, seed=seed)
    first = summary(to_json(res), truth)
    t1 = time.perf_counter()
    T_new = {"val": t_val, "est": t_est, "case": DESIGN_S.get(name, t_val)}[duration]
    d = design_experiment(res, est, val, duration=T_new, n_steps=steps, seed=seed, criterion=criterion)
    t2 = time.perf_counter()
    out = {"case": name, "seed": seed, "truth": truth, "effects": eff, "zones": zones, "noise": noise,
           "estimation_s": t_est, "record_s": T_new, "prbs_diagnosis": first,
           "design": design_json(d), "design_seconds": t2 - t1, "diagnose_seconds": t1 - t0}
    for kind, uu in (("designed", d["u"]), ("prbs", d["u_prbs"])):
        recs = {"est": est, "val": val,
                "new": run_printer(pr, np.asarray(uu), 10 * seed + 3, noise, u_rest, measured),
                "new2": run_printer(pr, np.asarray(uu), 10 * seed + 4, noise, u_rest, measured)}
        for how, e, v in ARMS:
            res_n = diagnose(recs[e], recs[v], seed=seed)
            r = summary(to_json(res_n), truth)
            r["input_dependence_z"] = res_n["localisation"].get("drift_input_dependence_records_z")
            r["named_truth"] = r["top"] == truth
            r["rival_left"] = bool(r["rivals"])
            out[f"{kind}_{how}"] = r
    weakest = int(np.argmin([v["designed"] for v in d["pair_separations"].values()]))
    arrays = {"u": d["u"], "u_prbs": d["u_prbs"], "gap": d["gaps"][weakest], "gap_prbs": d["gaps_prbs"][weakest],
              "pair": list(d["pair_separations"])[weakest], "history": d["history"]}
    return out, arrays


def figure(rows, arrays, path):
    """Per case (first seed): the designed and the PRBS input in separate lanes, and the weakest
    pair's prediction gap left after the nuisance refit, in noise units, on both."""
    from matplotlib.figure import Figure

    from jthermo.plots import save_figure

    fig = Figure(figsize=(11, 2.3 * len(rows)), layout="constrained")
    axes = fig.subplots(len(rows), 2, squeeze=False, width_ratios=(1, 1.3))
    for r, (a1, a2) in zip(rows, axes):
        ar = arrays[(r["case"], r["seed"])]
        t = np.arange(len(ar["u"]))
        lo, hi = r["design"]["limits"]["u_min"][0], r["design"]["limits"]["u_max"][0]
        span = hi - lo
        a1.step(t, ar["u"][:, 0], where="post", lw=0.9, color="tab:blue", label="designed")
        a1.step(t, ar["u_prbs"][:, 0] - 1.4 * span, where="post", lw=0.8, color="0.45", label="PRBS (offset)")
        a1.set_yticks([lo - 1.4 * span, hi - 1.4 * span, lo, hi],
                      [f"{lo:.2f}", f"{hi:.2f}", f"{lo:.2f}", f"{hi:.2f}"], fontsize="x-small")
        a1.set_ylabel("heater command")
        a1.set_title(f"{r['case']} (truth {r['truth']}): designed (top), PRBS (below), hold "
                     f"{r['design']['hold']} s", fontsize="small")
        g, gp = ar["gap"], ar["gap_prbs"]
        a2.plot(t, gp, lw=0.7, color="0.45", label=f"PRBS  S = {np.sum(gp ** 2):.3g}")
        a2.plot(t, g, lw=0.9, color="tab:blue", label=f"designed  S = {np.sum(g ** 2):.3g}")
        a2.axhspan(-1, 1, color="tab:orange", alpha=0.15, lw=0, label="±1 noise σ")
        a2.set_ylabel("gap / σ")
        a2.legend(fontsize="x-small", loc="upper right", ncol=3)
        a2.set_title(f"weakest pair {ar['pair'].replace('/', ' vs ')}: gap after the nuisance refit",
                     fontsize="small")
    for a in axes[-1]:
        a.set_xlabel("time (s)")
    save_figure(fig, path)


ARM_LABEL = {"as_validation": "as val", "as_estimation": "as est", "twice": "twice (est + val)"}


def write(rows, out, load):
    """The Markdown table and the JSON of `rows`."""
    yes = lambda b: "yes" if b else "no"
    crit = rows[0]["design"].get("criterion", "span")
    arms = [a for a, _, _ in ARMS if f"designed_{a}" in rows[0]]
    lines = ["# Designed experiments against PRBS", "",
             (f"Made by `experiments/design_experiment_study.py` (criterion `{crit}`). Virtual printer, one "
              "zone, Ts = 1 s, white +"),
             "AR(1) sensor noise (same noise draw in both arms); PRBS estimation + validation records are",
             "diagnosed first; the design separates the top finding and its rivals (with no rival: the top",
             "finding, the runner-up and the baseline; with no finding the two best candidates and the",
             "baseline); then the designed record and a PRBS record of the same length, limits and minimum",
             "switching time (10 s) are run on the same printer. Separation S = the models' prediction gap",
             "outside what a new record's re-estimated nuisances absorb (`jthermo/diagnose/experiment.py`),",
             "over the noise power, for the weakest pair. Seeds: printer s, PRBS 10s+1, noise 10s+2, new",
             "records' noise (and surroundings) 10s+3, the rerun's 10s+4.",
             f"Load average when the table was written (1, 5, 15 min): {load}; the machine was shared.", "",
             "Each new record is diagnosed as the validation record (models fitted on the PRBS",
             "estimation record: the protocol the design assumes), as the estimation record (validated",
             "on the PRBS validation record) and, where run, twice: the same input run again as the",
             "validation record. Cells: named truth? (top finding; rivals left).", "",
             (f"Slow body against drift: the designed and PRBS records of these two cases are "
              f"{DESIGN_S.get('body')} s long (a 40-min body"),
             "shows in no 15-min record). The diagnosis orders the two by whether the unmeasured",
             "surroundings drift the drift model fits follows the input-driven temperature (`bodydrift.input_dependence`),",
             "tested on every record with at least 8 drift knots (2400 s) and combined (`bodydrift.combined_dependence`):",
             "the 1800-s PRBS estimation record is too short, so as validation only the new record's test counts,",
             "as estimation only its own, twice both.", "",
             "## Counts (top finding = truth, over seeds)", "",
             "| case | truth | seeds | new record s | PRBS est/val | "
             + " | ".join(f"new PRBS {ARM_LABEL[a]} | designed {ARM_LABEL[a]}" for a in arms)
             + " | rival left as val: PRBS/designed | median S designed / PRBS |",
             "|---|---|---|---|---|" + "---|---|" * len(arms) + "---|---|"]
    cases = list(dict.fromkeys(r["case"] for r in rows))
    for c in cases:
        rs = [r for r in rows if r["case"] == c]
        k = lambda key, sub="named_truth", rs=rs: f"{sum(bool(r[key][sub]) for r in rs)}/{len(rs)}"
        first = f"{sum(r['prbs_diagnosis']['top'] == r['truth'] for r in rs)}/{len(rs)}"
        lines.append(f"| {c} | {rs[0]['truth']} | {len(rs)} | {rs[0].get('record_s', '-')} | {first} | "
                     + " | ".join(f"{k('prbs_' + a)} | {k('designed_' + a)}" for a in arms)
                     + f" | {k('prbs_as_validation', 'rival_left')} / {k('designed_as_validation', 'rival_left')} | "
                     f"{np.median([r['design']['separation_designed'] for r in rs]):.3g} / "
                     f"{np.median([r['design']['separation_prbs'] for r in rs]):.3g} |")
    tot = lambda key, sub="named_truth": f"{sum(bool(r[key][sub]) for r in rows)}/{len(rows)}"
    lines += ["", f"All: PRBS est/val {sum(r['prbs_diagnosis']['top'] == r['truth'] for r in rows)}/{len(rows)}; "
              + "; ".join(f"{ARM_LABEL[a]} designed {tot('designed_' + a)} (rival left "
                          f"{tot('designed_' + a, 'rival_left')}), PRBS of the same length {tot('prbs_' + a)} "
                          f"(rival left {tot('prbs_' + a, 'rival_left')})" for a in arms) + ".", "",
              "## Every run", "",
              "Input dependence z of the body/drift test (`bodydrift.input_dependence`), estimation / validation",
              "record (0: too short to test, fewer than 8 drift knots), shown for the designed record's arms.", "",
              ("| case | seed | PRBS est/val: top (rivals) | models separated | "
               + " | ".join(f"new PRBS {ARM_LABEL[a]} | designed {ARM_LABEL[a]}" for a in arms)
               + " | weakest-pair S designed / PRBS | truth's tests, designed as val: z/z_crit, LR/LR_crit | "
                 "truth's LR/LR_crit as est: designed / PRBS |"),
              "|---|---|---|---|" + "---|---|" * len(arms) + "---|---|---|"]

    def cell(c, dep=False):
        z = c.get("input_dependence_z")
        zs = f"; z_in {z[0]:.2f}/{z[1]:.2f}" if dep and z else ""
        return f"{yes(c['named_truth'])} ({c['top']}; {', '.join(c['rivals']) or '-'}{zs})"

    def tests(c):
        t = c.get("truth_tests")
        return "-" if not t else (f"{t['validation_z']:.2f}/{t['validation_z_critical']:.2f}, "
                                  f"{t['estimation_lr']:.1f}/{t['estimation_lr_critical']:.1f}")
    def lr(c):
        t = c.get("truth_tests")
        return "-" if not t else f"{t['estimation_lr']:.1f}/{t['estimation_lr_critical']:.1f}"
    for r in rows:
        f = r["prbs_diagnosis"]
        slow = r["truth"] in ("heat_accumulation", "ambient_variation")
        lines.append(f"| {r['case']} | {r.get('seed', 0)} | {f['top']} ({', '.join(f['rivals']) or '-'}) | "
                     f"{' / '.join(r['design']['rivals'])} | "
                     + " | ".join(f"{cell(r['prbs_' + a])} | {cell(r['designed_' + a], slow)}" for a in arms)
                     + f" | {r['design']['separation_designed']:.3g} / "
                     f"{r['design']['separation_prbs']:.3g} = {r['design']['separation_ratio']:.2f} | "
                     f"{tests(r['designed_as_validation'])} | {lr(r['designed_as_estimation'])} / "
                     f"{lr(r['prbs_as_estimation'])} |")
    lines += ["", "![inputs and rival prediction gaps](design_experiment_study.png)", ""]
    atomic_write_text(out / "design_experiment_study.md", "\n".join(lines))
    atomic_write_text(out / "design_experiment_study.json", json.dumps(rows, indent=1, default=float))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--seeds", default="0", help="comma-separated printer/noise seeds, each case on each")
    ap.add_argument("--criterion", default="nuisance", choices=("nuisance", "nuisance_drift", "span"))
    ap.add_argument("--duration", default="case", choices=("case", "val", "est"),
                    help="designed record's length: the case's (`DESIGN_S`, else the validation record's), "
                         "the validation record's or the estimation record's")
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--out", default="experiments/results")
    ap.add_argument("--rewrite", metavar="LOAD", help="only rewrite the Markdown from the JSON in --out")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.rewrite is not None:
        rows = json.loads((out / "design_experiment_study.json").read_text())
        write(rows, out, args.rewrite)
        return 0
    rows, arrays = [], {}
    seeds = [int(x) for x in args.seeds.split(",")]
    for seed in seeds:
        for name in args.cases.split(","):
            t0 = time.perf_counter()
            row, ar = run_case(name, args.steps, seed, args.criterion, args.duration)
            row["seconds"] = time.perf_counter() - t0
            rows.append(row)
            arrays[(name, seed)] = ar
            got = "; ".join(f"{k} {row[k]['top']} {row[k]['rivals']}" for k in
                            (f"{w}_{a}" for a, _, _ in ARMS for w in ("prbs", "designed")))
            print(f"{name} seed {seed}: PRBS est/val {row['prbs_diagnosis']['top']} rivals "
                  f"{row['prbs_diagnosis']['rivals']}; design {row['design']['rivals']} "
                  f"x{row['design']['separation_ratio']:.2f}; {got} ({row['seconds']:.0f} s)", flush=True)
            load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
            rows.sort(key=lambda r: (list(CASES).index(r["case"]), r["seed"]))
            write(rows, out, load)
    figure([r for r in rows if r["seed"] == seeds[0]], arrays, out / "design_experiment_study.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
