"""`jthermo demo`: the whole workflow on the built-in virtual printer, ending in a report.

Stages: PRBS experiment → fit every model family → design controllers → tune by gradient →
residual tests → the three test scenarios (tracking, powder, print) → diagnose a concealed
effect → `runs/<name>/report.md` with figures, `summary.json`, the data, the models and the
tuned controller. Each stage is guarded: a stage that fails (or whose library piece is missing) is
reported in the report with its one-line reason, and the later stages go on without it. The
diagnosis and the tuning (on the virtual printer's own design model) need nothing from the
stages before them and run in two more threads beside them; the scenarios (stage 6) run beside
the residual tests (stage 5).
"""

from __future__ import annotations

import functools
import importlib
import time
from pathlib import Path
from typing import Any

import numpy as np

from .demo_stages import SETTINGS, StageRunner, demo_settings, in_background  # noqa: F401
from .errors import JThermoError

#: every model family with the orders the demo fits (MATLAB's order)
FAMILY_ORDERS: dict[str, tuple[int, ...] | None] = {
    "arx": (2, 2, 1), "armax": (2, 2, 2, 1), "oe": (2, 2, 1), "bj": (2, 1, 1, 2, 1),
    "ss": (4,), "greybox": None}

ID_EFFECTS = ("lateral_conduction", "radiative_loss", "sensor_noise")
CONCEALED = ("heater_lag", {"time_constant_s": 25.0})


@functools.cache
def _quick_simulate():
    """`closedloop.simulate` as one program with `runtime.simulate_compile()` options (the
    scenario figures' runs; their scenarios from `closedloop.compiled_make_scenario`): cold,
    the three take less CPU time than eager runs with default options."""
    import equinox as eqx

    from .closedloop import simulate
    from .runtime import simulate_compile

    return eqx.filter_jit(simulate, compiler_options=simulate_compile())


def _progress(desc: str, quiet: bool, total: int | None = None):
    from .progress import Progress

    return Progress(total, desc, quiet=True if quiet else None)


def run_demo(name: str = "demo", *, quick: bool = False, seed: int = 0, runs_dir: str = "runs",
             quiet: bool = False, zones: int | None = None) -> dict:
    """Run the demo and write `runs_dir/name/report.md`; returns the summary dict. `zones`:
    the virtual printer's (default `SETTINGS`' 4; `demo_settings`)."""
    from . import io
    from .data import save_csv

    cfg = demo_settings(quick, zones)
    root = Path(runs_dir) / name
    figs = root / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    st = StageRunner(9, quiet)
    t_start = time.perf_counter()
    S: dict[str, Any] = {"name": name, "quick": quick, "seed": seed, "settings": cfg}
    figures: dict[str, list[tuple[Path, str]]] = {}

    def fig(section, path, caption):
        figures.setdefault(section, []).append((Path(path), caption))

    # 1 -------------------------------------------------------------- experiment
    def experiment():
        from .printer import generate, make_printer

        p = make_printer(cfg["zones"], ID_EFFECTS, seed=seed)
        est = generate(p, "prbs", cfg["est_s"], seed=seed)
        val = generate(p, "prbs", cfg["val_s"], seed=seed + 1)
        save_csv(est, root / "data" / "estimation.csv")
        save_csv(val, root / "data" / "validation.csv")
        S["experiment"] = {"zones": cfg["zones"], "effects": list(ID_EFFECTS),
                           "estimation_samples": est.n_samples, "validation_samples": val.n_samples,
                           "inputs": list(est.input_names), "outputs": list(est.output_names),
                           "signals": list(est.signal_names)}
        return est, val

    ev = st.run("PRBS experiment on the virtual printer", experiment)
    est, val = ev if ev is not None else (None, None)

    # 7 -------------------------------------------------------------- diagnosis (started early)
    # independent of every other stage: it runs in a second thread from here on, so that its
    # compilations and fits overlap theirs (a second core, or the time one stage waits on its
    # compiler); its stage waits for it below
    def diagnosis():
        from .diagnose import diagnose
        from .printer import generate, make_printer

        eff_name, eff_params = CONCEALED
        p = make_printer(cfg["zones"], {eff_name: eff_params}, seed=seed + 5)
        d_est = generate(p, "prbs", cfg["diag_est_s"], seed=seed + 7)
        d_val = generate(p, "prbs", cfg["diag_val_s"], seed=seed + 8)
        bar = _progress("diagnose", True)
        try:
            res = diagnose(d_est, d_val, seed=seed, progress=bar)
        finally:
            bar.close()
        try:
            from .diagnose import write_report

            write_report(res, root / "diagnosis", d_est, d_val)
            S["diagnosis_report"] = "diagnosis/report.md"
        except ImportError:
            pass
        S["diagnosis"] = {k: v for k, v in res.items() if not str(k).startswith("_")
                          and k in ("verdict", "baseline", "findings", "augmented", "seconds")}
        S["diagnosis"]["concealed"] = {"mechanism": eff_name, **eff_params}

    # 4 -------------------------------------------------------------- tuning (started early)
    # on the virtual printer's own design model: independent of the fits, so it runs beside
    # them in a third thread; the tuned PI joins the designed controllers when it is done
    tuned_box: dict[str, Any] = {}

    def tune_stage():
        from .tune import tune_report

        bar = _progress("tune pi_lambda", True, cfg["tune_steps"])
        try:
            rep = tune_report("pi_lambda", plant="printer", zones=cfg["zones"],
                              rollouts=cfg["tune_rollouts"],
                              steps=cfg["tune_steps"], lr=cfg["tune_lr"], seed=seed,
                              duration=cfg["scenario_s"], eval_rollouts=cfg["eval_rollouts"],
                              changed_powder=None, progress=bar)
        finally:
            bar.close()
        tuned = rep.pop("tuned")
        tuned_box["pi_lambda (tuned)"] = tuned
        io.save(tuned, root / "models" / "pi_lambda_tuned.jtm", meta={"family": "pi_lambda", "seed": seed})
        S["tuning"] = {k: v for k, v in rep.items() if k != "history"}
        S["tuning_history"] = rep["history"]
        try:
            from . import plots

            plots.plot_tuning_curve(rep["history"], path=figs / "tuning.png")
            fig("tuning", figs / "tuning.png", "Mean closed-loop cost over the tuning iterations")
        except ModuleNotFoundError:
            pass

    diagnosing = in_background(diagnosis)
    tuning = in_background(tune_stage)

    # 2 -------------------------------------------------------------- identification + validation
    models: dict[str, Any] = {}

    def identification():
        from .identify.fit import fit
        from .validate import compare

        rows = []
        yhat = {}
        for fam, orders in FAMILY_ORDERS.items():
            bar = _progress(f"fit {fam}", quiet)
            try:
                res = fit(est, fam, orders, seed=seed, progress=bar, n_starts=cfg["n_starts"])
                cmp = compare(res.model, val)
            except JThermoError as exc:
                rows.append({"model": fam, "error": " ".join(str(exc).split())})
                continue
            finally:
                bar.close()
            models[fam] = res.model
            yhat[fam] = cmp["yhat"]
            io.save(res.model, root / "models" / f"{fam}.jtm",
                    meta={"family": fam, "orders": res.orders, "seed": seed})
            rows.append({"model": fam, "orders": res.orders, "fit_percent": cmp["fit_percent"],
                         "mean_fit_percent": cmp["mean_fit_percent"], "converged": res.converged,
                         "seconds": res.seconds})
            st.say(f"      {fam:8s} fit {cmp['mean_fit_percent']:6.2f} % ({res.seconds:.1f} s)")
        S["identification"] = rows
        if not models:
            raise JThermoError("no model family could be fitted")
        try:
            from . import plots

            plots.plot_compare(val, yhat, {r["model"]: r["fit_percent"] for r in rows if "fit_percent" in r},
                               path=figs / "compare.png")
            fig("identification", figs / "compare.png", "Validation data against each model's simulation (fit %)")
            plots.plot_step(models, 600, path=figs / "step.png")
            fig("identification", figs / "step.png", "Step responses of every fitted model")
            plots.plot_pzmap(models, path=figs / "pzmap.png")
            fig("identification", figs / "pzmap.png", "Poles and zeros")
        except ModuleNotFoundError:
            pass

    if est is not None:
        st.run("fit every model family and validate", identification)
    else:
        st.records.append({"stage": "fit every model family and validate", "status": "skipped",
                           "message": "no data"})

    # 3 -------------------------------------------------------------- controller design
    controllers: dict[str, Any] = {}
    plant_box: dict[str, Any] = {}

    def design_stage():
        from .closedloop import REALISTIC_EFFECTS
        from .control.design import FAMILIES, design
        from .printer import make_printer
        from .tune import printer_model

        plant = make_printer(cfg["zones"], REALISTIC_EFFECTS, seed=0)
        plant_box["plant"] = plant
        base = models.get("ss") or printer_model(plant)
        S["design_model"] = "ss (fitted)" if "ss" in models else "printer linearised"
        rows = []
        for fam in FAMILIES:
            try:
                controllers[fam] = design(fam, base)
                rows.append({"controller": fam, "status": "designed"})
            except JThermoError as exc:
                rows.append({"controller": fam, "status": " ".join(str(exc).split())})
        S["design"] = rows

    st.run("design controllers from the fitted model", design_stage)

    st.run("tune lambda-PI by gradient over vmapped rollouts (run beside stages 2-3)", tuning)
    controllers.update(tuned_box)

    # 6 -------------------------------------------------------------- scenarios
    def scenarios():
        import jax

        from . import closedloop as cl
        from .tune import HELD_OUT, SCENARIOS, evaluate

        plant = plant_box.get("plant")
        if plant is None:
            from .printer import make_printer

            plant = make_printer(cfg["zones"], cl.REALISTIC_EFFECTS, seed=0)
        rows = []
        names = list(controllers)
        if quick:  # the baseline, the classical PI, one model-based design and the tuned one
            names = [n for n in names if n in ("pi_untuned", "pi_lambda", "lqg", "pi_lambda (tuned)")]
        bar = _progress("scenarios", quiet, len(names))
        try:
            for i, n in enumerate(names):
                try:
                    ev = evaluate(controllers[n], plant, SCENARIOS, (seed + HELD_OUT,),
                                  rollouts=cfg["eval_rollouts"], duration=cfg["scenario_s"])
                except JThermoError as exc:
                    rows.append({"controller": n, "error": " ".join(str(exc).split())})
                    continue
                row = {"controller": n, "mean cost": ev["cost"]}
                for k in SCENARIOS:
                    row[f"MSE {k}"] = ev["scenarios"][k]["mse"]
                rows.append(row)
                bar(i + 1, len(names), {"controller": n})
        finally:
            bar.close()
        S["scenarios"] = rows
        from . import plots

        best = "pi_lambda (tuned)" if "pi_lambda (tuned)" in controllers else names[0]
        for k in SCENARIOS:
            sc = cl.compiled_make_scenario()(k, plant, cfg["scenario_s"], jax.random.key(seed + HELD_OUT))
            tr = _quick_simulate()(plant, controllers[best], cl.unlabelled(sc))  # one program
            t = np.arange(sc.n_samples) * sc.ts
            plots.plot_closed_loop(t, np.asarray(tr.y), np.asarray(tr.u), np.asarray(tr.r),
                                   path=figs / f"closed_loop_{k}.png")
            fig("scenarios", figs / f"closed_loop_{k}.png", f"{k} scenario, {best}: temperatures "
                "with the ±1 °C window, and heater inputs")
            if k == "print":
                from .printer import grid_shape

                rows_, cols_ = grid_shape(cfg["zones"])
                plots.plot_bed_heatmap(np.asarray(tr.y)[-1], rows_, cols_,
                                       title="Bed temperatures at the end of the print scenario",
                                       path=figs / "bed_heatmap.png")
                fig("scenarios", figs / "bed_heatmap.png", "Zone temperatures over the bed (print scenario, last sample)")

    # the scenarios' compilations (one program per controller structure) overlap the residual
    # stage's tests and figures: started here, waited for after it
    scenarios_done = in_background(scenarios) if controllers else None

    # 5 -------------------------------------------------------------- residual tests
    def residuals():
        from . import plots
        from .validate import residual_tests, spectral_estimate

        ok = [r for r in S.get("identification", []) if "mean_fit_percent" in r]
        best = max(ok, key=lambda r: r["mean_fit_percent"])["model"]
        res = residual_tests(models[best], val)
        S["validation"] = {"best": best, "whiteness_pass": res.get("whiteness_pass"),
                           "independence_pass": res.get("independence_pass"),
                           "ljung_box_p": res.get("ljung_box_p")}
        plots.plot_residual_tests(res, path=figs / "residuals.png")
        fig("validation", figs / "residuals.png", f"Residual tests of the best model ({best})")
        spec = spectral_estimate(val)
        # each heater's own zone and one neighbour coupling: all ny x nu channels of a 4-zone
        # bed are 32 log axes, several times the drawing time (python benchmarks/demo_bode.py)
        m = models[best]
        chans = [(i, i) for i in range(min(m.n_outputs, m.n_inputs))]
        chans += [(1, 0)] if m.n_outputs > 1 else []
        plots.plot_bode({best: m}, spectral=spec, channels=chans, path=figs / "bode.png")
        fig("validation", figs / "bode.png", f"Bode diagram of {best} against the spectral estimate "
            "(each heater to its own zone, and heater 1 to zone 2)")

    if models:
        st.run("residual and spectral validation", residuals)
    else:
        st.records.append({"stage": "residual and spectral validation", "status": "skipped"})

    if scenarios_done is not None:
        st.run("the three test scenarios against the virtual printer (run beside stage 5)",
               scenarios_done)
    else:
        st.records.append({"stage": "the three test scenarios against the virtual printer",
                           "status": "skipped", "message": "no controller"})

    st.run("diagnose a concealed effect (run beside stages 2-6)", diagnosing)
    st.run("settle a tie by one designed experiment (one zone)", lambda: S.update(
        tie=importlib.import_module(".diagnose.tie_demo", __package__).settle_tie(seed)))

    # 8 -------------------------------------------------------------- report
    S["stages"] = st.records
    S["seconds"] = round(time.perf_counter() - t_start, 1)

    def write():
        path = write_demo_report(root, S, figures)
        S["report"] = str(path)

    st.run("write the report", write)
    S["stages"] = st.records
    S.setdefault("report", str(root / "report.md"))
    from .io import write_json

    write_json(root / "summary.json", S)
    return S


def write_demo_report(root: Path, S: dict, figures: dict) -> Path:
    from .report import Report

    rep = Report(f"jthermo demo — {S['name']}")
    rep.para(f"The whole workflow on the built-in virtual printer ({S['settings']['zones']} zones"
             f"{', quick settings' if S['quick'] else ''}, seed {S['seed']}), in {S['seconds']:.0f} s. "
             "Every number below comes from this run; `summary.json` holds them all.")
    rep.heading("Stages")
    rep.table([{"stage": r["stage"], "status": r["status"], "seconds": r.get("seconds"),
                "note": r.get("message", "")} for r in S["stages"]])

    def figs(section):
        for p, caption in figures.get(section, []):
            rep.figure(p, caption)

    exp = S.get("experiment")
    rep.heading("1. Experiment")
    if exp:
        rep.para(f"Independent band-limited PRBS on each of the {exp['zones']} heaters; the printer has "
                 f"{', '.join(exp['effects'])} switched on. {exp['estimation_samples']} estimation and "
                 f"{exp['validation_samples']} validation samples at Ts = 1 s, in `data/`.")
    rep.heading("2. Identification and validation")
    if S.get("identification"):
        rows = [{"family": r["model"], "orders": r.get("orders") or r.get("error", "—"),
                 "validation fit % (per zone)": [round(x, 1) for x in r.get("fit_percent", [])],
                 "mean fit %": r.get("mean_fit_percent"), "converged": r.get("converged"),
                 "seconds": r.get("seconds")} for r in S["identification"]]
        rep.para("Simulation fit on the validation experiment, "
                 "`100 (1 - ||y - ŷ|| / ||y - mean y||)` per zone. Models are saved in `models/`.")
        rep.table(rows)
        figs("identification")
    v = S.get("validation")
    if v:
        rep.para(f"Best model: **{v['best']}**. Residuals white: {v['whiteness_pass']}; independent of "
                 f"the inputs: {v['independence_pass']}.")
        figs("validation")
    rep.heading("3. Controller design")
    if S.get("design"):
        rep.para(f"Designed from the {S.get('design_model')} model.")
        rep.table(S["design"])
    rep.heading("4. Gradient tuning")
    t = S.get("tuning")
    if t:
        rep.para(f"Lambda-tuned diagonal PI (designed on the printer's linearisation, "
                 "`tune.printer_model`), tuned by `jax.grad` of the mean closed-loop cost over "
                 f"{t.get('rollouts')} vmapped disturbance rollouts for {t.get('steps')} Adam steps, "
                 f"evaluated on held-out seeds {t.get('held_out_seeds')}.")
        rep.table([{"start cost": t.get("start_cost"), "tuned cost": t.get("tuned_cost"),
                    "lambda-PI cost": t.get("lambda_pi_cost"),
                    "improvement %": t.get("improvement_percent"), "seconds": t.get("seconds")}])
        if t.get("scenarios"):
            rep.table([{"scenario": k, **v} for k, v in t["scenarios"].items()])
        figs("tuning")
    rep.heading("5. Test scenarios")
    if S.get("scenarios"):
        rep.para("Each controller against the virtual printer with every realistic effect on "
                 "(not the model it was designed from), held-out disturbance seed; MSE in °C². "
                 f"Classical designs come from the {S.get('design_model', 'fitted')} model, the tuned "
                 "one from section 4.")
        rep.table(S["scenarios"])
        figs("scenarios")
    rep.heading("6. Diagnosis of a concealed effect")
    d = S.get("diagnosis")
    if d:
        c = d["concealed"]
        rep.para(f"Recordings made with `{c['mechanism']}` switched on ("
                 + ", ".join(f"{k} = {v}" for k, v in c.items() if k != "mechanism")
                 + "), diagnosed blind.")
        base, aug = d.get("baseline", {}), d.get("augmented") or {}
        rep.bullets([f"verdict: **{d.get('verdict')}**",
                     f"baseline grey-box fit: {base.get('mean_fit_percent', float('nan')):.2f} %",
                     (f"augmented ({', '.join(aug.get('mechanisms', [])) or '—'}) fit: "
                      f"{aug.get('mean_fit_percent', float('nan')):.2f} %")])
        if d.get("findings"):
            rep.table([{"mechanism": f.get("mechanism"), "confidence": f.get("confidence"),
                        "zones": f.get("zones"), "parameters": f.get("parameters"),
                        "summary": f.get("summary")} for f in d["findings"]])
        if S.get("diagnosis_report"):
            rep.para(f"Full diagnosis report: [{S['diagnosis_report']}]({S['diagnosis_report']}).")
    importlib.import_module(".diagnose.tie_demo", __package__).report_section(rep, S.get("tie"))
    failed = [r for r in S["stages"] if r["status"] != "ok"]
    if failed:
        rep.heading("Stages that did not complete")
        rep.bullets(f"{r['stage']}: {r['status']} — {r.get('message', '')}" for r in failed)
    return rep.write(root / "report.md")
