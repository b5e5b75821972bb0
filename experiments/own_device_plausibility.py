"""Is the default `jthermo fit` of a user's own heater a plant heat could be?

Per real heater recording in `../shared/data/real/` (TCLab kits, the Klipper hot-end heat tests,
the heat-ups in the Klipper printer logs) and per family (arx, armax, oe, bj, ss, greybox):
`jthermo fit REC --model F` with every default (automatic orders), run in-process. Tabulated:
the exit status, the plausibility findings of the fitted model judged on its own recording
(`models.plausibility.heat_check`: unstable, a heater that lowers a sensor's steady temperature,
an inverse step response beyond the noise, steady states that do not cover the recorded
temperatures), the fit % `jthermo fit` reports (simulation fit on the estimation record), the
orders and the selection path of the physics constraint (`--json`'s `physics`).

Usage:  python experiments/own_device_plausibility.py [--records all|issue|NAME,...]
            [--families arx,oe,...] [--physics heat|none] [--data-dir DIR]
Writes `experiments/results/own_device_plausibility.md` (overwritten).
"""

from __future__ import annotations

import argparse
import contextlib
import io as _io
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from jthermo import io as jio  # noqa: E402
from jthermo.cli import main as cli_main  # noqa: E402
from jthermo.data import load  # noqa: E402
from jthermo.families import MODEL_FAMILIES  # noqa: E402
from jthermo.models.plausibility import heat_check  # noqa: E402

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


def one(rec: str, family: str, physics: str, tmp: Path) -> dict:
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
        row["error"] = err.getvalue().strip().splitlines()[-1] if err.getvalue().strip() else ""
        return row
    rep = json.loads(js.read_text())
    model = jio.load_model(mod)
    data = load(path_of(rec))
    from jthermo.data import keep_inputs, keep_outputs

    data = keep_outputs(keep_inputs(data, rep["inputs"]), rep["outputs"])
    sig = rep.get("signals")
    if sig is not None:
        keep = [data.signal_names.index(n) for n in sig]
        data = data.replace(w=data.w[:, keep], signal_names=tuple(sig))
    chk = heat_check(model, data)
    row.update(fit=rep["mean_fit_percent"], orders=rep["orders"], warnings=chk["warnings"],
               plausible=chk["plausible"], physics=rep.get("physics"),
               cli_warnings=rep.get("warnings", []))
    return row


def render(rows: list[dict], argv: list[str]) -> str:
    ok = [r for r in rows if r["rc"] == 0]
    good = [r for r in ok if r["plausible"]]
    lines = ["# Default fits of real heater recordings: plausible?", "",
             f"Command: `python experiments/own_device_plausibility.py {' '.join(argv)}`", "",
             f"**{len(good)} of {len(rows)} default fits give a plausible model** "
             f"({len(rows) - len(ok)} exit non-zero, {len(ok) - len(good)} exit 0 with a "
             "plausibility finding).", "",
             "Fit: simulation fit % on the estimation record (what `jthermo fit` reports without "
             "`--validation`). Findings: `models.plausibility.heat_check` of the fitted model on "
             "its own recording.", "",
             "| record | family | exit | fit % | orders | findings | physics path |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["rc"] != 0:
            lines.append(f"| {r['record']} | {r['family']} | {r['rc']} | | | "
                         f"{r.get('error', '')[:160]} | |")
            continue
        f = "; ".join(w[:120] for w in r["warnings"]) or "none"
        ph = r.get("physics") or {}
        path = " → ".join(ph.get("path", [])) if isinstance(ph, dict) else ""
        o = ",".join(f"{k}={v}" for k, v in (r["orders"] or {}).items())
        lines.append(f"| {r['record']} | {r['family']} | 0 | {r['fit']:.1f} | {o} | {f} | "
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
    args = ap.parse_args(argv)
    REAL = Path(args.data_dir) if args.data_dir else REAL
    shown = [a for k, a in enumerate(argv) if a != "--data-dir" and
             (k == 0 or argv[k - 1] != "--data-dir")]
    recs = (all_records() if args.records == "all" else ISSUE if args.records == "issue"
            else args.records.split(","))
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for rec in recs:
            for fam in args.families.split(","):
                r = one(rec, fam, args.physics, Path(d))
                print(r["record"], fam, r["rc"], r.get("fit"), r.get("warnings") or r.get("error"),
                      flush=True)
                rows.append(r)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(render(rows, shown))
    print(OUT.read_text().splitlines()[4])


if __name__ == "__main__":
    main()
