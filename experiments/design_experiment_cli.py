"""`jthermo diagnose EST --validation VAL --design-experiment OUT.csv` end to end, from the shell.

On a virtual-printer record pair (the study's `lag` case, seed 0) and on real single-heater
recordings (Klipper OnionHeater hot end: `heattest_fan_200` estimation, `heattest_fan_200_2`
validation, and the reverse; TCLab CACE 2020, two heaters and one heater, `id_*` estimation,
`val_*` validation), the command is run as a user would (a subprocess); the written
OUT.csv must load with `jthermo.data.load` in the estimation record's layout and stay within the
recorded input limits and the minimum switching time; bad options must fail with exit code 2 and
one line on stderr, before the diagnosis runs.

    .venv/bin/python experiments/design_experiment_cli.py [--out experiments/results]
        [--sets virtual,klipper,tclab]

Writes `experiments/results/design_experiment_cli{T}.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT / ".." / "shared" / "data" / "real" / "klipper_onionheater"
TCLAB = ROOT / ".." / "shared" / "data" / "real" / "tclab_cace2020"
SETS = ("virtual", "klipper", "tclab")
JT = [str(Path(sys.executable).parent / "jthermo")]     # the installed command, as from the shell


def _shown(path) -> str:
    """A record's path as the results show it: relative to the repository beside ../shared,
    else its name (a temporary file): no path of this machine in committed results."""
    path = Path(path).resolve()
    if path.is_relative_to(ROOT.parent.resolve()):
        return os.path.relpath(path, ROOT)
    return path.name


def sh(args, timeout=900):
    t0 = time.perf_counter()
    p = subprocess.run(JT + [str(a) for a in args], capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stderr.strip(), time.perf_counter() - t0


def virtual_pair(tmp):
    sys.path.insert(0, str(ROOT / "experiments"))
    import design_experiment_study as S

    from jthermo import printer as P
    from jthermo.data import save_csv
    from jthermo.inputs import prbs

    truth, eff, zones, t_est, t_val, levels, hold, noise, measured = S.CASES["lag"]
    pr = P.make_printer(zones, effects=eff, seed=0)
    u = np.asarray(prbs(1, t_est + t_val, pr.n_inputs, levels=levels, hold=hold), float)
    rec = S.run_printer(pr, u, 2, noise, 0.5 * sum(levels), measured)
    est = rec.replace(u=rec.u[:t_est], y=rec.y[:t_est], w=rec.w[:t_est])
    val = rec.replace(u=rec.u[t_est:], y=rec.y[t_est:], w=rec.w[t_est:], t0=float(t_est))
    pe, pv = tmp / "printer_est.csv", tmp / "printer_val.csv"
    save_csv(est, pe)
    save_csv(val, pv)
    return pe, pv


def check_design(name, pe, pv, tmp, hold_s=10.0):
    from jthermo.data import load

    out, js = tmp / f"{name}_next.csv", tmp / f"{name}.json"
    rc, err, secs = sh(["diagnose", pe, "--validation", pv, "--design-experiment", out,
                        "--design-hold", hold_s, "--json", js, "--quiet"])
    row = {"case": name, "est": _shown(pe), "val": _shown(pv), "rc": rc, "seconds": round(secs, 1),
           "stderr_tail": err.splitlines()[-1] if err else ""}
    if rc != 0:
        return row
    e, v, d = load(pe), load(pv), load(out)
    res = json.loads(js.read_text())
    x = res["experiment"]
    U = np.concatenate([e.u, v.u])
    lo, hi = U.min(axis=0), U.max(axis=0)
    hold = max(1, round(hold_s / e.ts))
    du = np.flatnonzero(np.any(np.diff(d.u, axis=0) != 0, axis=1)) + 1
    runs = np.diff(np.r_[0, du, d.n_samples])
    row.update({"findings": [f["mechanism"] for f in res.get("findings", [])],
                "rivals": (res.get("findings") or [{}])[0].get("rivals", []),
                "separated": x["rivals"], "why": x["why"], "criterion": x.get("criterion"),
                "separation_designed": x["separation_designed"], "separation_prbs": x["separation_prbs"],
                "y_max": x.get("y_max"), "y_max_effective": x.get("y_max_effective"), "within_y_max": x.get("within_y_max"), "max_predicted": x.get("max_predicted"),
                "max_predicted_prbs": x.get("max_predicted_prbs"), "recorded_max": float(max(e.y.max(), v.y.max())),
                "loads": True, "same_layout": (d.input_names == e.input_names and d.output_names == e.output_names
                                               and abs(d.ts - e.ts) < 1e-9),
                "samples": d.n_samples, "est_samples": e.n_samples,
                "within_limits": bool(np.all(d.u >= lo - 1e-9) and np.all(d.u <= hi + 1e-9)),
                "limits": [lo.tolist(), hi.tolist()], "u_range": [d.u.min(axis=0).tolist(), d.u.max(axis=0).tolist()],
                "shortest_run_samples": int(runs[:-1].min()) if runs.size > 1 else int(runs[0]),
                "hold_samples": hold})
    row["holds"] = row["shortest_run_samples"] >= hold
    return row


def bad_options(pe, pv, tmp):
    out = tmp / "x.csv"
    cases = {"hold 0": ["--design-experiment", out, "--design-hold", "0"],
             "hold -5": ["--design-experiment", out, "--design-hold", "-5"],
             "duration 0": ["--design-experiment", out, "--design-duration", "0"],
             "duration shorter than two holds": ["--design-experiment", out, "--design-duration", "15",
                                                 "--design-hold", "10"],
             "hold not a number": ["--design-experiment", out, "--design-hold", "ten"],
             "OUT is a directory": ["--design-experiment", tmp],
             "OUT under a file": ["--design-experiment", pe / "next.csv"],
             "OUT same as --json": ["--design-experiment", out, "--json", out]}
    rows = []
    for what, extra in cases.items():
        rc, err, secs = sh(["diagnose", pe, "--validation", pv, *extra, "--quiet"])
        rows.append({"option": what, "rc": rc, "lines": len(err.splitlines()), "stderr": err, "seconds": round(secs, 1),
                     "ok": rc == 2 and len(err.splitlines()) == 1 and "Traceback" not in err})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="experiments/results")
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--sets", default=",".join(SETS), help=f"comma-separated of {', '.join(SETS)}")
    args = ap.parse_args(argv)
    sets = [x for x in args.sets.split(",") if x and not (args.skip_real and x != "virtual")]
    out = Path(args.out)
    tmp = Path(tempfile.mkdtemp(prefix="jthermo_design_cli_"))
    rows, bad = [], []
    if "virtual" in sets:
        pe, pv = virtual_pair(tmp)
        rows.append(check_design("virtual printer (lag, seed 0)", pe, pv, tmp))
        print(rows[-1], flush=True)
    if "klipper" in sets:
        a, b = REAL / "heattest_fan_200" / "data.csv", REAL / "heattest_fan_200_2" / "data.csv"
        for name, (e, v) in (("klipper fan_200 -> fan_200_2", (a, b)), ("klipper fan_200_2 -> fan_200", (b, a))):
            rows.append(check_design(name, e.resolve(), v.resolve(), tmp))
            print(rows[-1], flush=True)
    if "tclab" in sets:
        for k in ("2heaters", "1heater"):
            e, v = TCLAB / f"id_{k}" / "data.csv", TCLAB / f"val_{k}" / "data.csv"
            rows.append(check_design(f"tclab cace2020 id_{k} -> val_{k}", e.resolve(), v.resolve(), tmp))
            print(rows[-1], flush=True)
    if "virtual" in sets:
        bad = bad_options(pe, pv, tmp)
    for r in bad:
        print(r, flush=True)
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    yes = lambda b: "yes" if b else "no"
    lines = ["# `jthermo diagnose ... --design-experiment OUT.csv` from the shell", "",
             "Made by `experiments/design_experiment_cli.py` (each command a subprocess, `--quiet`). "
             f"Load average at the end (1, 5, 15 min): {load}; the machine was shared.", "",
             "| records | exit | s wall | findings (rivals) | separated | S designed / PRBS | loads, same layout | "
             "samples (est) | within recorded limits | shortest run / hold (samples) | highest predicted °C: designed / "
             "PRBS (limit = recorded max; effective: at least what holding the rest input reaches) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["rc"] != 0:
            lines.append(f"| {r['case']} | {r['rc']} | {r['seconds']} | {r['stderr_tail']} | | | | | | | |")
            continue
        lines.append(f"| {r['case']} | {r['rc']} | {r['seconds']} | {', '.join(r['findings']) or '-'} "
                     f"({', '.join(r['rivals']) or '-'}) | {' / '.join(r['separated'])} | "
                     f"{r['separation_designed']:.3g} / {r['separation_prbs']:.3g} | "
                     f"{yes(r['loads'] and r['same_layout'])} | {r['samples']} ({r['est_samples']}) | "
                     f"{yes(r['within_limits'])} {r['u_range']} in {r['limits']} | "
                     f"{r['shortest_run_samples']} / {r['hold_samples']} ({yes(r['holds'])}) | "
                     f"{r['max_predicted'] and [round(v, 1) for v in r['max_predicted']]} / "
                     f"{[round(v, 1) for v in r['max_predicted_prbs']]} ({[round(v, 1) for v in r['y_max']]}; "
                     f"effective {[round(v, 1) for v in r.get('y_max_effective') or r['y_max']]}, "
                     f"within: {yes(r['within_y_max'])}) |")
    lines += ["", "Bad options (on the virtual-printer pair): exit code 2 and one stderr line, before the diagnosis:", "",
              "| option | exit | stderr lines | s wall | stderr | ok |", "|---|---|---|---|---|---|"]
    for r in bad:
        lines.append(f"| {r['option']} | {r['rc']} | {r['lines']} | {r['seconds']} | `{r['stderr']}` | {yes(r['ok'])} |")
    out.mkdir(parents=True, exist_ok=True)
    (out / "design_experiment_cli.md").write_text("\n".join(lines) + "\n")
    (out / "design_experiment_cli.json").write_text(json.dumps({"runs": rows, "bad_options": bad},
                                                                          indent=1))
    return 0 if all(r["ok"] for r in bad) and all(r["rc"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
