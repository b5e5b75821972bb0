"""Designed experiments against PRBS on the virtual printer (issue 14 item 3).

For each case the printer hides one mechanism of a rival pair that PRBS records tend to leave
tied (heater lag / input delay, a slow chamber body / an unmeasured surroundings drift,
radiation / lamp nonlinearity). A PRBS estimation and validation record are diagnosed; the
input that separates the two explanations (`jthermo.diagnose.experiment.design_experiment`, the
top finding and its rival, or the top finding and the baseline when there is no rival) is run
on the true printer, and the diagnosis is repeated with that record as the validation record
(the models are fitted on the same estimation record). The comparison is a PRBS record of the
same length, actuator limits and minimum switching time, run on the same printer.

    .venv/bin/python experiments/design_experiment_study.py [--cases a,b] [--steps 150] [--out experiments/results]

Writes `experiments/results/design_experiment.md`, `.json` and `design_experiment.png`.
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
from jthermo.diagnose.experiment import design_experiment, predictions, rival_context
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


def summary(res):
    f = res["findings"]
    return {"top": f[0]["mechanism"] if f else None, "rivals": f[0]["rivals"] if f else [],
            "named": [x["mechanism"] for x in f], "confidence": f[0]["confidence"] if f else None,
            "fit": res["augmented"]["mean_fit_percent"]}


def ctx_of(res, est, val, d):
    """The design's simulation context again (for the PRBS predictions in the figure)."""
    u_rest = np.clip(np.mean(est.u, axis=0), d["limits"]["u_min"], d["limits"]["u_max"])
    return rival_context(res["_models"], tuple(d["rivals"]), d["duration"], float(est.ts), u_rest,
                         np.mean(est.y, axis=0))


def run_case(name, steps, seed=0):
    truth, eff, zones, t_est, t_val, levels, hold, noise, measured = CASES[name]
    pr = P.make_printer(zones, effects=eff, seed=seed)
    u_rest = 0.5 * (levels[0] + levels[1])
    u = np.asarray(prbs(seed + 1, t_est + t_val, pr.n_inputs, levels=levels, hold=hold), float)
    rec = run_printer(pr, u, seed + 2, noise, u_rest, measured)
    est = rec.replace(u=rec.u[:t_est], y=rec.y[:t_est], w=rec.w[:t_est])
    val = rec.replace(u=rec.u[t_est:], y=rec.y[t_est:], w=rec.w[t_est:], t0=float(t_est))
    t0 = time.perf_counter()
    res = diagnose(est, val, seed=seed)
    first = summary(to_json(res))
    t1 = time.perf_counter()
    d = design_experiment(res, est, val, duration=t_val, n_steps=steps, seed=seed)
    t2 = time.perf_counter()
    out = {"case": name, "truth": truth, "effects": eff, "zones": zones, "noise": noise,
           "estimation_s": t_est, "record_s": t_val, "prbs_diagnosis": first,
           "design": design_json(d), "design_seconds": t2 - t1, "diagnose_seconds": t1 - t0}
    for kind, uu in (("designed", d["u"]), ("prbs", d["u_prbs"])):
        new = run_printer(pr, np.asarray(uu), seed + 3, noise, u_rest, measured)
        for how, (e, v) in (("as_validation", (est, new)), ("as_estimation", (new, val))):
            r = summary(to_json(diagnose(e, v, seed=seed)))
            r["named_truth"] = r["top"] == truth
            r["rival_left"] = bool(r["rivals"])
            out[f"{kind}_{how}"] = r
    yp = np.asarray(predictions(jax.numpy.asarray(d["u_prbs"]), ctx_of(res, est, val, d)))
    arrays = {"u": d["u"], "u_prbs": d["u_prbs"], "gap": d["predictions"][0] - d["predictions"][1],
              "gap_prbs": yp[0] - yp[1], "history": d["history"]}
    return out, arrays


def figure(rows, arrays, path):
    from matplotlib.figure import Figure

    from jthermo.plots import save_figure

    fig = Figure(figsize=(10, 2.1 * len(rows)), layout="constrained")
    axes = fig.subplots(len(rows), 2, squeeze=False)
    for r, (a1, a2) in zip(rows, axes):
        ar = arrays[r["case"]]
        t = np.arange(len(ar["u"]))
        a1.step(t, ar["u_prbs"][:, 0], lw=0.6, color="0.6", label="PRBS")
        a1.step(t, ar["u"][:, 0], lw=0.9, color="tab:blue", label="designed")
        a1.set_ylabel("u")
        a1.set_title(f"{r['case']}: truth {r['truth']}; design separates "
                     f"{' / '.join(r['design']['rivals'])}", fontsize="small")
        a1.legend(fontsize="x-small", loc="upper right")
        a2.plot(t, ar["gap"][:, 0], lw=0.8, color="tab:blue", label="designed")
        a2.plot(t, ar["gap_prbs"][:, 0], lw=0.6, color="0.6", label="PRBS")
        a2.set_ylabel("ŷ_top − ŷ_rival (°C)")
        a2.legend(fontsize="x-small", loc="upper right")
        a2.set_title(f"prediction gap of the first two models; weakest-pair separation ×"
                     f"{r['design']['separation_ratio']:.1f} of PRBS", fontsize="small")
    for a in axes[-1]:
        a.set_xlabel("time (s)")
    save_figure(fig, path)


def write(rows, out, load):
    yes = lambda b: "yes" if b else "no"
    lines = ["# Designed experiments against PRBS (issue 14 item 3)", "",
             "Made by `experiments/design_experiment_study.py`. Virtual printer, one zone, Ts = 1 s, white +",
             "AR(1) sensor noise (same noise draw in both arms); PRBS estimation + validation records are",
             "diagnosed first; the design separates the top finding and its rivals (or the top finding and",
             "the baseline, or with no finding the two best candidates); then the designed record and a",
             "PRBS record of the same length, limits and minimum switching time (10 s) are run on the same",
             "printer. Separation = the models' prediction gap outside what a new record's nuisances absorb",
             "(initial level; drift when the surroundings are unmeasured), over the noise power, for the",
             "weakest pair (`jthermo/diagnose/experiment.py`).",
             f"Load average when the table was written (1, 5, 15 min): {load}; the machine was shared.", "",
             "Each new record is diagnosed twice: as the validation record (models fitted on the PRBS",
             "estimation record: the protocol the design assumes) and as the estimation record (validated",
             "on the PRBS validation record). Cells: named truth? (top finding; rivals left).", "",
             ("| case | truth | PRBS est/val: top (rivals) | models separated | new PRBS as val | designed as val | "
              "new PRBS as est | designed as est | weakest-pair separation designed / PRBS |"),
             "|---|---|---|---|---|---|---|---|---|"]
    cell = lambda c: f"{yes(c['named_truth'])} ({c['top']}; {', '.join(c['rivals']) or '-'})"
    for r in rows:
        f = r["prbs_diagnosis"]
        lines.append(f"| {r['case']} | {r['truth']} | {f['top']} ({', '.join(f['rivals']) or '-'}) | "
                     f"{' / '.join(r['design']['rivals'])} | {cell(r['prbs_as_validation'])} | "
                     f"{cell(r['designed_as_validation'])} | {cell(r['prbs_as_estimation'])} | "
                     f"{cell(r['designed_as_estimation'])} | {r['design']['separation_designed']:.3g} / "
                     f"{r['design']['separation_prbs']:.3g} = {r['design']['separation_ratio']:.2f} |")
    count = lambda kind, key: f"{sum(r[kind][key] for r in rows)}/{len(rows)}"
    lines += [""]
    for how in ("as_validation", "as_estimation"):
        lines.append(f"- new record {how.replace('_', ' ')}: designed named the truth "
                     f"{count('designed_' + how, 'named_truth')} (rival left "
                     f"{count('designed_' + how, 'rival_left')}); PRBS of the same length "
                     f"{count('prbs_' + how, 'named_truth')} (rival left {count('prbs_' + how, 'rival_left')})")
    lines += ["", "![inputs and rival prediction gaps](design_experiment.png)", ""]
    atomic_write_text(out / "design_experiment.md", "\n".join(lines))
    atomic_write_text(out / "design_experiment.json", json.dumps(rows, indent=1, default=float))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--out", default="experiments/results")
    ap.add_argument("--rewrite", metavar="LOAD", help="only rewrite the Markdown from the JSON in --out")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.rewrite is not None:
        write(json.loads((out / "design_experiment.json").read_text()), out, args.rewrite)
        return 0
    rows, arrays = [], {}
    for name in args.cases.split(","):
        t0 = time.perf_counter()
        row, ar = run_case(name, args.steps)
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        arrays[name] = ar
        got = "; ".join(f"{k} {row[k]['top']} {row[k]['rivals']}" for k in
                        ("prbs_as_validation", "designed_as_validation", "prbs_as_estimation",
                         "designed_as_estimation"))
        print(f"{name}: PRBS est/val {row['prbs_diagnosis']['top']} rivals {row['prbs_diagnosis']['rivals']}; "
              f"design {row['design']['rivals']} x{row['design']['separation_ratio']:.2f}; {got} "
              f"({row['seconds']:.0f} s)", flush=True)
        load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
        write(rows, out, load)
    figure(rows, arrays, out / "design_experiment.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
