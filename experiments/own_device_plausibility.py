"""Is the default `jthermo fit` of a user's own heater a plant heat could be?

Per real heater recording in `../shared/data/real/` (TCLab kits, the Klipper hot-end heat tests,
the heat-ups in the Klipper printer logs) and per family (arx, armax, oe, bj, ss, greybox):
`jthermo fit REC --model F` with every default (automatic orders), run in-process. Tabulated:
the exit status, the plausibility findings of the fitted model judged on its own recording
(`models.plausibility.heat_check`: unstable, a heater that lowers a sensor's steady temperature,
an inverse step response beyond the noise, steady states that do not cover the recorded
temperatures), the fit % `jthermo fit` reports (simulation fit on the estimation record), the
orders and the selection path of the physics constraint (`--json`'s `physics`).

Before and after: `--package DIR --save-models M` runs the fits with the `jthermo` package found
in DIR (an older checkout, e.g. `git archive <commit> jthermo | tar -x -C DIR`) and keeps each
fitted model and report in M; a later run with `--before M` judges those models with this
checkout's `heat_check` and tabulates them beside its own fits (exit, fit %, plausible); a
saved model that took the record's logged set point as a measured signal (†) predicted a closed
loop's temperature from its own set point and is not compared. Rows are kept one a line in
`--rows FILE` as they finish, so an interrupted run resumes (delete a row to rerun it).

Usage:  python experiments/own_device_plausibility.py [--records all|issue|NAME,...]
            [--families arx,oe,...] [--physics heat|none] [--data-dir DIR]
            [--package DIR] [--save-models M] [--before M] [--rows FILE]
Writes `experiments/results/own_device_plausibility.md` (overwritten; not with --package).
"""

from __future__ import annotations

import argparse
import contextlib
import io as _io
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
_pkg = [a for k, a in enumerate(sys.argv) if k and sys.argv[k - 1] == "--package"]
sys.path.insert(0, _pkg[0] if _pkg else str(ROOT))

from jthermo import io as jio  # noqa: E402
from jthermo.cli import main as cli_main  # noqa: E402
from jthermo.data import load  # noqa: E402
from jthermo.families import MODEL_FAMILIES  # noqa: E402

try:
    from jthermo.models.plausibility import heat_check  # noqa: E402
except ImportError:         # an older package (--package): its models are judged later
    heat_check = None

REAL = ROOT.parent / "shared" / "data" / "real"
OUT = ROOT / "experiments" / "results" / "own_device_plausibility.md"

#: the records the issue's table named, plus one heat-up per printer log
ISSUE = ["tclab_cace2020/val_1heater", "tclab_cace2020/val_2heaters", "tclab_apm_mimo_steps",
         "tclab_rawlings/prbs_mlid2024", "tclab_kantor_cbe30338/step_q1_50_a",
         "klipper_onionheater/heattest_200", "klipper_onionheater/heattest_fan_200",
         "klipper_onionheater/heattest_fan_200_2", "klipper_onionheater/sample_trace",
         "klipper_logs/kp3s_b20bob/0912_extruder_seg02.csv",
         "klipper_logs/voron24_lahn92/heater_bed_seg01.csv",
         "klipper_logs/ender3pro_gunny0201/extruder_seg01.csv"]


def all_records() -> list[str]:
    """Every TCLab run, every Klipper hot-end run and every printer-log CSV."""
    out = []
    for d in sorted(REAL.glob("tclab_*")) + [REAL / "klipper_onionheater"]:
        runs = sorted(p.parent for p in d.glob("*/data.csv")) or [d]
        out += [str(p.relative_to(REAL)) for p in runs]
    out += [str(p.relative_to(REAL)) for p in sorted((REAL / "klipper_logs").glob("*/*.csv"))]
    return out


def path_of(rec: str) -> Path:
    p = REAL / rec
    return p if p.suffix == ".csv" else p / "data.csv"


def slug(rec: str, family: str) -> str:
    return rec.replace("/", "__").removesuffix(".csv") + f"__{family}"


def judge(rec: str, rep: dict, mod: Path) -> dict:
    """The plausibility of a saved fit, judged on its own recording with the columns it took."""
    from jthermo.data import keep_inputs, keep_outputs

    model = jio.load_model(mod)
    data = keep_outputs(load(path_of(rec)), rep["outputs"])
    sig = rep.get("signals")
    if sig is not None:
        keep = [data.signal_names.index(n) for n in sig]
        data = data.replace(w=data.w[:, keep], signal_names=tuple(sig))
    if (rep.get("physics") or {}).get("rest_samples"):
        from jthermo.identify.heat import heat_data

        data = heat_data(data)[0]
    data = keep_inputs(data, rep["inputs"])
    chk = heat_check(model, data)
    return {"warnings": chk["warnings"], "plausible": chk["plausible"]}


def one(rec: str, family: str, physics: str, tmp: Path, keep: Path | None) -> dict:
    js, mod = tmp / "fit.json", tmp / "model.jtm"
    for p in (js, mod):
        p.unlink(missing_ok=True)
    argv = ["fit", str(path_of(rec)), "--model", family, "--json", str(js), "--out", str(mod),
            "--quiet"]
    if physics != "heat":
        argv += ["--physics", physics]
    err = _io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = cli_main(argv)
    row = {"record": rec, "family": family, "rc": rc}
    if rc != 0:
        msg = err.getvalue().strip().splitlines()[-1] if err.getvalue().strip() else ""
        row["error"] = msg.replace(str(REAL) + "/", "")
        return row
    rep = json.loads(js.read_text())
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        shutil.copy(mod, keep / f"{slug(rec, family)}.jtm")
        shutil.copy(js, keep / f"{slug(rec, family)}.json")
    row.update(fit=rep["mean_fit_percent"], orders=rep["orders"], physics=rep.get("physics"))
    if heat_check is not None:
        row.update(judge(rec, rep, mod))
    return row


def before_row(rec: str, family: str, models: Path) -> dict:
    """The fit a `--save-models` run left for this record and family, judged now."""
    js, mod = models / f"{slug(rec, family)}.json", models / f"{slug(rec, family)}.jtm"
    if not js.exists():
        return {"rc": 2}
    rep = json.loads(js.read_text())
    return {"rc": 0, "fit": rep["mean_fit_percent"], **judge(rec, rep, mod),
            "setpoint_signal": used_setpoint(rec, mod)}


def used_setpoint(rec: str, mod: Path) -> bool:
    """Did the saved model take a logged set point (`w_*target*`, `w_*setpoint*`, `w_*set_point*`)
    as a measured signal? Such a model predicts a closed loop's temperature from its own set
    point: its fit is no plant's and is not compared."""
    from jthermo.models.plausibility import is_setpoint_signal

    n = jio.load_model(mod).n_signals
    return any(is_setpoint_signal(x) for x in load(path_of(rec)).signal_names[:n])


def _cell(r: dict | None) -> str:
    if r is None:
        return "not run"
    if r["rc"] != 0:
        return "exit 2"
    return f"{r['fit']:.1f}" + ("" if r["plausible"] else " ✗") + (" †" if r.get("setpoint_signal")
                                                                     else "")


def render(rows: list[dict], argv: list[str], before: bool) -> str:
    ok = [r for r in rows if r["rc"] == 0]
    good = [r for r in ok if r["plausible"]]
    lines = ["# Default fits of real heater recordings: plausible?", "",
             f"Command: `python experiments/own_device_plausibility.py {' '.join(argv)}`", "",
             f"**{len(good)} of {len(rows)} default fits give a plausible model** "
             f"({len(rows) - len(ok)} exit non-zero, {len(ok) - len(good)} exit 0 with a "
             "plausibility finding).", ""]
    if before:
        b = [r["before"] for r in rows if r.get("before") is not None]
        b_ok = [r for r in b if r["rc"] == 0]
        lines += [f"The package before the heat path, on the same rows: **"
                  f"{sum(r['plausible'] for r in b_ok)} of {len(b)} plausible** "
                  f"({len(b) - len(b_ok)} exit non-zero, "
                  f"{sum(not r['plausible'] for r in b_ok)} exit 0 with a finding).", ""]
        was = [r for r in rows if (r.get("before") or {}).get("rc") == 0
               and r["before"]["plausible"]]
        drops = [(r, r["before"]["fit"] - (r["fit"] if r["rc"] == 0 else -np.inf)) for r in was
                 if not r["before"].get("setpoint_signal")]
        worst = [t for t in sorted(drops, key=lambda t: -t[1])[:5] if t[1] > 1.0]
        sp = [r for r in was if r["before"].get("setpoint_signal")]
        if drops:
            lines += [f"Of {len(drops)} rows plausible before (set-point models aside), "
                      f"{sum(d > 1.0 for _, d in drops)} lose more than 1 point of fit"
                      + (": " + "; ".join(f"{r['record']} {r['family']} {r['before']['fit']:.1f} "
                                          f"→ {_cell(r)}"
                                          for r, _ in worst) if worst else "") + ".", ""]
        if sp:
            lines += [f"† {len(sp)} models before took the record's logged set point as a measured "
                      "signal (a closed loop's temperature predicted from its own set point), which "
                      "the heat path leaves out; their fits are not compared: "
                      + "; ".join(f"{r['record']} {r['family']} {r['before']['fit']:.1f} → "
                                  f"{_cell(r)}" for r in sp) + ".", ""]
    lines += ["Fit: simulation fit % on the estimation record (what `jthermo fit` reports without "
              "`--validation`). Findings: `models.plausibility.heat_check` of the fitted model on "
              "its own recording (✗: a finding).", ""]
    head = "| record | family | " + ("before | " if before else "") + \
        "exit | fit % | orders | findings | physics path |"
    lines += [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        pre = f"{_cell(r.get('before'))} | " if before else ""
        if r["rc"] != 0:
            lines.append(f"| {r['record']} | {r['family']} | {pre}{r['rc']} | | | "
                         f"{r.get('error', '')[:160]} | |")
            continue
        f = "; ".join(w[:120] for w in r["warnings"]) or "none"
        ph = r.get("physics") or {}
        path = " → ".join(ph.get("path", [])) if isinstance(ph, dict) else ""
        o = ",".join(f"{k}={v}" for k, v in (r["orders"] or {}).items())
        lines.append(f"| {r['record']} | {r['family']} | {pre}0 | {r['fit']:.1f} | {o} | {f} | "
                     f"{path[:200]} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    global REAL
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser()
    ap.add_argument("--records", default="issue", help="all, issue, or comma-separated names")
    ap.add_argument("--families", default=",".join(MODEL_FAMILIES))
    ap.add_argument("--physics", default="heat", choices=("heat", "none"))
    ap.add_argument("--data-dir", default=None,
                    help="the real recordings (default ../shared/data/real beside the repo)")
    ap.add_argument("--package", help="run the jthermo package found in this directory")
    ap.add_argument("--save-models", help="keep each fitted model and report here")
    ap.add_argument("--before", help="models and reports a --save-models run left: tabulated")
    ap.add_argument("--rows", help="rows one a line as they finish (resumed when present)")
    ap.add_argument("--table-only", action="store_true",
                    help="fit nothing: tabulate the rows of --rows (the others: not run)")
    args = ap.parse_args(argv)
    REAL = Path(args.data_dir).resolve() if args.data_dir else REAL
    hidden = ("--data-dir", "--package", "--save-models", "--before", "--rows")
    shown = [a for k, a in enumerate(argv) if a not in hidden and
             (k == 0 or argv[k - 1] not in hidden)]
    if args.before:
        shown.append("--before MODELS")
    recs = (all_records() if args.records == "all" else ISSUE if args.records == "issue"
            else args.records.split(","))
    done = {}
    rows_file = Path(args.rows) if args.rows else None
    if rows_file is not None and rows_file.exists():
        for line in rows_file.read_text().splitlines():
            r = json.loads(line)
            done[(r["record"], r["family"])] = r
    rows, missing = [], []
    keep = Path(args.save_models) if args.save_models else None
    with tempfile.TemporaryDirectory() as d:
        for rec in recs:
            for fam in args.families.split(","):
                if args.table_only and (rec, fam) not in done:
                    missing.append(f"{rec} {fam}")
                    continue
                r = done.get((rec, fam)) or one(rec, fam, args.physics, Path(d), keep)
                if (rec, fam) not in done and rows_file is not None:
                    with rows_file.open("a") as fh:
                        fh.write(json.dumps(r) + "\n")
                if args.before:
                    r["before"] = before_row(rec, fam, Path(args.before))
                print(r["record"], fam, r["rc"], r.get("fit"), r.get("warnings") or r.get("error"),
                      flush=True)
                rows.append(r)
    if args.package:
        return
    OUT.parent.mkdir(parents=True, exist_ok=True)
    text = render(rows, [a for a in shown if a != "--table-only"], bool(args.before))
    if missing:
        text += (f"\nNot run in this pass ({len(missing)} of {len(missing) + len(rows)} fits, "
                 "the time it had on a shared machine): " + ", ".join(missing) + ".\n")
    OUT.write_text(text)
    print(OUT.read_text().splitlines()[4])


if __name__ == "__main__":
    main()
