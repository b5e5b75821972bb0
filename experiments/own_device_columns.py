"""A user's own device whose log has more columns than its model: the CLI path, measured.

1. A one-heater TCLab record that logs both heaters (`u_Q2` held at 0) and both sensors
   (`tclab_dowling_pyomo_doe`): `fit` leaves out the idle heater; `--outputs T1` keeps the heated
   zone's sensor; `validate` picks the model's columns from a full record; `tune` designs and
   tunes the SISO loop at the record's temperature.
2. A validation record at another operating point (`tclab_rawlings`, two days): the fit is
   negative and `level_offsets` says it is a level shift.

    .venv/bin/python experiments/own_device_columns.py

Writes `experiments/results/own_device_columns.md` and `.json`.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
OUT = ROOT / "experiments" / "results" / "own_device_columns"


def jthermo(args: list, tmp: Path, name: str) -> dict:
    """Run `jthermo ARGS --json TMP/NAME.json --quiet`: exit status, stderr, the report."""
    js = tmp / f"{name}.json"
    t = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "jthermo.cli", *map(str, args), "--json", str(js),
                        "--quiet"], capture_output=True, text=True, cwd=ROOT)
    rep = json.loads(js.read_text()) if js.exists() else None
    return {"argv": " ".join(map(str, args)).replace(str(REAL) + "/", ""), "rc": p.returncode,
            "stderr": p.stderr.strip(), "wall_s": round(time.perf_counter() - t, 1), "report": rep}


def main() -> None:
    d, r = REAL / "tclab_dowling_pyomo_doe", REAL / "tclab_rawlings"
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        both, q1 = tmp / "both.jtm", tmp / "q1.jtm"
        rows["fit (all sensors)"] = jthermo(["fit", d / "sine_5min_run1/data.csv", "--model", "ss",
                                             "--validation", d / "sine_5min_run2/data.csv",
                                             "--out", both], tmp, "fit_both")
        rows["fit --outputs T1"] = jthermo(["fit", d / "sine_5min_run1/data.csv", "--model", "ss",
                                            "--outputs", "T1", "--validation",
                                            d / "sine_5min_run2/data.csv", "--out", q1], tmp, "fit_q1")
        rows["validate on run 3"] = jthermo(["validate", q1, d / "sine_5min_run3/data.csv"], tmp, "val_q1")
        rows["validate on a step (heater held)"] = jthermo(["validate", q1, d / "step50_run1/data.csv"],
                                                           tmp, "val_step")
        rows["tune pi (two sensors)"] = jthermo(["tune", "--controller", "pi", "--model", both], tmp,
                                                "tune_both")
        rows["tune pi (T1)"] = jthermo(["tune", "--controller", "pi", "--model", q1], tmp, "tune_q1")
        rows["rawlings: fit, another day's validation"] = jthermo(
            ["fit", r / "prbs_kr2022/data.csv", "--model", "ss", "--validation",
             r / "prbs_mlid2024/data.csv"], tmp, "fit_rawlings")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    def portable(text: str) -> str:      # no path of this machine in the results
        return text.replace(str(REAL), "../shared/data/real").replace(str(tmp), "TMP")

    OUT.with_suffix(".json").write_text(portable(json.dumps(rows, indent=1, default=str)))
    lines = ["# A device whose log has more columns than its model (CLI)", "",
             "`python experiments/own_device_columns.py`: each call a `jthermo` process (`--json`, "
             "`--quiet`); real recordings from `../shared/data/real/`.", "",
             "| step | call | exit | wall s | figures | stderr (last line) |", "|---|---|---|---|---|---|"]
    for step, row in rows.items():
        rep = row["report"] or {}
        figs = []
        if "fit_percent" in rep:
            figs.append("fit % " + " / ".join(f"{f:.1f}" for f in rep["fit_percent"]))
        if rep.get("dropped_inputs"):
            figs.append(f"inputs {rep['inputs']}, left out {rep['dropped_inputs']}")
        if rep.get("outputs"):
            figs.append(f"outputs {rep['outputs']}")
        for o in rep.get("level_offsets") or []:
            if o["shifted"]:
                figs.append(f"{o['output']} shifted {o['mean_error']:+.2f} ({100 * o['share']:.0f} % of "
                            f"the squared error, std {o['output_std']:.2f})")
        rt = rep.get("residual_tests") or {}
        if rt.get("constant_inputs"):
            figs.append(f"constant inputs {rt['constant_inputs']}, independence {rt['independence_pass']}")
        if "setpoints" in rep:
            figs.append(f"set point {[round(s, 2) for s in rep['setpoints']]} °C, held-out cost "
                        f"{rep['tuned_vs_start_percent']:.1f} % below the start, "
                        f"{rep['improvement_percent']:.1f} % below lambda PI")
        last = row["stderr"].splitlines()[-1] if row["stderr"] else ""
        lines.append(f"| {step} | `jthermo {row['argv']}` | {row['rc']} | "
                     f"{row['wall_s']} | {'; '.join(figs)} | {last} |")
    OUT.with_suffix(".md").write_text(portable("\n".join(lines) + "\n"))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
