"""The path a user walks, audited: every CLI command with its default options, as subprocesses.

A matrix of `jthermo` calls (each in its own process, with a timeout): `generate` -> `fit`
(state space with the default order, then every family at its default orders) -> `validate` ->
`tune` (pi, lqg on the fitted model as the plant) -> `simulate` -> `export` (C, JSON) ->
`diagnose` -> `sweep` at N = 1, 2, 3, 7, 9, 12, 16, 19 zones; `fit` / `validate` / `tune` /
`diagnose` on the real recordings of `../shared/data/real/`; bad inputs, each of which must exit 2
with one `jthermo: error:` line on stderr and no traceback; and a user's first calls with an
empty compilation cache (`cold`).

Per call: exit status, wall time and CPU s of the child (user+sys), the last stderr line, and
checks on the `--json` report: every number finite, fit % in (-inf, 100] and a state-space
fit on virtual-printer data above 50 %, a tuning result at the user's plant's sample time with
its set point inside the recorded range and a tuned loop that reaches it, a diagnosis that
names nothing on a record of the plain bed (no effect switched on).

Records are shorter at many zones so that the audit fits in ~30 CPU min (`RECORD_S`); the
families beyond `ss`/`arx` run at N <= 3 only at the defaults (`--families-all` for every N).

Usage:
    .venv/bin/python experiments/default_path_audit.py [--only zones,real,bad,cold]
        [--zones 1,3] [--commands fit,tune] [--families-all] [--out experiments/results]
    .venv/bin/python experiments/default_path_audit.py --render experiments/results/X.json
Writes `experiments/results/default_path_audit.md` and `.json`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
#: the `jthermo` of the running interpreter's environment (a worktree without its own venv)
EXE = next((p for p in (Path(sys.executable).with_name("jthermo"),
                        ROOT / ".venv" / "bin" / "jthermo") if p.exists()),
           ROOT / ".venv" / "bin" / "jthermo")

ZONES = (1, 2, 3, 7, 9, 12, 16, 19)
#: record length (s) per zone count: the default 1 s sample time; shorter at many zones
RECORD_S = {1: 1800, 2: 1800, 3: 1800, 7: 1200, 9: 1200, 12: 900, 16: 600, 19: 600}
FAMILIES = ("arx", "armax", "oe", "bj", "greybox")
COMMANDS = ("generate", "fit", "families", "validate", "tune", "simulate", "export", "diagnose",
            "sweep")

#: real recordings: (label, estimation, validation or None, tune and diagnose?, what `fit`
#: must do: "ok" or the reason it must refuse the record with)
REAL_CASES = [
    ("tclab_cace2020 2 heaters", "tclab_cace2020/id_2heaters", "tclab_cace2020/val_2heaters", True,
     "ok"),
    ("klipper hot-end", "klipper_onionheater/heattest_200", "klipper_onionheater/sample_trace", True,
     "ok"),
    ("tclab_kantor step b->c (input on from the first sample)", "tclab_kantor_cbe30338/step_q1_50_b",
     "tclab_kantor_cbe30338/step_q1_50_c", False, "is constant"),
    ("tclab_dowling sine 5 min (Q2 = 0 logged: left out)", "tclab_dowling_pyomo_doe/sine_5min_run1",
     "tclab_dowling_pyomo_doe/sine_5min_run2", False, "ok"),
    ("tclab_rawlings (two devices/days)", "tclab_rawlings/prbs_kr2022",
     "tclab_rawlings/prbs_mlid2024", False, "ok"),
    ("tclab_apm_mimo_steps (set points as w_)", "tclab_apm_mimo_steps", None, False, "ok"),
    ("daisy_heating_system", "daisy_heating_system", None, False, "ok"),
    ("daisy_hair_dryer", "daisy_hair_dryer", None, False, "ok"),
    ("tclab_cace2020 mpc_arx_a (a 1.3 s step)", "tclab_cace2020/mpc_arx_a", None, False,
     "not uniform"),
]


# ---------------------------------------------------------------- running one call


def run(argv, timeout, cwd, env=None):
    """Run `jthermo argv` -> (exit status or 'timeout', wall s, CPU s, stdout, stderr)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        p = subprocess.run([str(EXE), *map(str, argv)], capture_output=True, text=True,
                           timeout=timeout, cwd=cwd, env=env)
        rc, out, err = p.returncode, p.stdout, p.stderr
    except subprocess.TimeoutExpired as exc:
        rc = "timeout"
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        err = exc.stderr.decode() if isinstance(exc.stderr, bytes) else (exc.stderr or "")
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return rc, wall, cpu, out, err


def non_finite(obj, path=""):
    """Paths of the non-finite numbers in a JSON object."""
    bad = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            bad += non_finite(v, f"{path}.{k}" if path else str(k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            bad += non_finite(v, f"{path}[{i}]")
    elif isinstance(obj, float) and not math.isfinite(obj):
        bad.append(path)
    return bad


def figures(rep) -> dict:
    """A few figures of a report, for the table: fit % range, what a diagnosis names, a closed
    loop's worst error, a tuning's gains."""
    out = {}
    fits = rep.get("fit_percent") or (rep.get("augmented") or {}).get("fit_percent")
    if fits:
        out["fit %"] = f"{min(fits):.4g}..{max(fits):.4g}" if len(fits) > 1 else f"{fits[0]:.4g}"
    if "augmented" in rep:
        out["names"] = ",".join(rep["augmented"].get("mechanisms") or []) or "-"
        conf = [f.get("confidence") for f in rep.get("findings") or []]
        if conf:
            out["confidence"] = max(c for c in conf if c is not None)
    m = rep.get("metrics") or {}
    if isinstance(m, dict) and "max_abs_error_C" in m:
        out["max abs e °C"] = round(m["max_abs_error_C"], 3)
        out["mean u"] = round(m.get("mean_input", float("nan")), 3)
    for k in ("improvement_percent", "tuned_vs_start_percent"):
        if isinstance(rep.get(k), (int, float)):
            out[k] = round(rep[k], 2)
    if "moved" in rep:
        out["moved"] = rep["moved"]
    return out


def last_line(text):
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1][:300] if lines else ""


class Audit:
    def __init__(self, work):
        self.work = Path(work)
        self.rows = []
        self.env = None   # the environment of the calls (None: this process's)
        self.slack = 1.0  # every call's timeout multiplied by this (a loaded machine)
        self.on_row = None  # called after every call (the results written so far)

    def call(self, group, name, argv, *, timeout=600, expect="ok", js=None, checks=()):
        """One CLI call; `checks` are functions of the report -> list of problems."""
        if js is not None:
            argv = [*argv, "--json", js]
        rc, wall, cpu, out, err = run(argv, timeout * self.slack, self.work, self.env)
        problems = []
        if "Traceback" in out + err:
            problems.append("traceback")
        report, fig = None, {}
        if expect == "ok":
            if rc != 0:
                problems.append(f"exit {rc}")
            elif js is not None:
                try:
                    report = json.loads((self.work / js).read_text())
                except (OSError, ValueError) as exc:
                    problems.append(f"no JSON report ({exc})")
                if report is not None:
                    fig = figures(report)
                    bad = non_finite(report)
                    if bad:
                        problems.append("non-finite: " + ", ".join(bad[:5]))
                    for check in checks:
                        problems += check(report)
        else:
            if rc == 0 and js is not None:   # a wrong success: what it reported
                try:
                    fig = figures(json.loads((self.work / js).read_text()))
                except (OSError, ValueError):
                    pass
            lines = [ln for ln in err.strip().splitlines() if ln.strip()]
            if rc != 2:
                problems.append(f"exit {rc} (want 2)")
            if len(lines) != 1 or not lines[0].startswith("jthermo: error:"):
                problems.append(f"{len(lines)} stderr lines, not one `jthermo: error:` line")
            if expect not in err:
                problems.append(f"message lacks `{expect}`")
        row = {"group": group, "name": name, "argv": ["jthermo", *map(str, argv)],
               "rc": rc, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
               "stderr_last": last_line(err), "ok": not problems, "problems": problems,
               "figures": fig}
        self.rows.append(row)
        flag = "ok  " if not problems else "FAIL"
        print(f"{flag} {group:10s} {name:42s} rc={rc} {wall:6.1f}s {cpu:6.1f}cpu "
              f"{'; '.join(problems)[:160]}", flush=True)
        if self.on_row is not None:
            self.on_row()
        return report


# ---------------------------------------------------------------- checks on reports


def fits_in_range(low=None):
    def check(rep):
        fits = rep.get("fit_percent") or []
        probs = []
        if not fits:
            probs.append("no fit_percent")
        if any(f is None or not math.isfinite(f) or f > 100.0 for f in fits):
            probs.append(f"fit % out of range {fits}")
        elif low is not None and min(fits) < low:
            probs.append(f"fit % {min(fits):.1f} < {low}")
        return probs
    return check


def tuned_on_own_plant(ts, y_lo, y_hi):
    """The tuning ran at the plant's sample time, its set point inside the recorded range, and
    the tuned loop reaches its set point (start-up settles, set-point changes followed)."""
    def check(rep):
        probs = []
        if ts is not None and abs(rep.get("ts", float("nan")) - ts) > 1e-9 * max(ts, 1):
            probs.append(f"ts {rep.get('ts')} != record's {ts}")
        sp = rep.get("setpoints") or []
        if not sp:
            probs.append("no setpoints")
        for s, lo, hi in zip(sp, y_lo, y_hi):
            if not lo - 1e-6 <= s <= hi + 1e-6:
                probs.append(f"set point {s:.3g} outside the record [{lo:.3g}, {hi:.3g}]")
        tuned = (rep.get("scenarios") or {}).get("tuned") or {}
        pre = tuned.get("preheat") or {}
        if pre and not (pre.get("time_to_ready_s") is not None
                        and math.isfinite(pre["time_to_ready_s"])):
            probs.append("tuned loop never ready at start-up")
        imp = rep.get("improvement_percent")
        if (imp is not None and imp > 0 and rep.get("tuned_cost", 0) >= rep.get("start_cost", 1)
                and "tuned_vs_start_percent" not in rep):
            probs.append("improvement > 0 (vs lambda PI) with a tuned cost not below its start, "
                         "and no figure of the tuning's own gain")
        return probs
    return check


def names_nothing(rep):
    named = (rep.get("augmented") or {}).get("mechanisms") or []
    return [f"names {named} on the plain bed"] if named else []


def files_exist(*paths):
    def check(_rep):
        return [f"missing {p}" for p in paths if not Path(p).exists()]
    return check


# ---------------------------------------------------------------- the matrix


def csv_range(path):
    """(ts, y_min, y_max) of a CSV record (the median step; outputs' range)."""
    import numpy as np
    with open(path) as fh:
        header = fh.readline().strip().split(",")
    a = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    t = a[:, header.index("t")]
    ys = [i for i, h in enumerate(header) if h.startswith("y_")]
    return float(np.median(np.diff(t))), a[:, ys].min(0).tolist(), a[:, ys].max(0).tolist()


def zone_cases(a: Audit, N: int, commands, families_all: bool):
    d = a.work / f"n{N}"
    d.mkdir(exist_ok=True)
    p = lambda name: f"n{N}/{name}"  # noqa: E731  (paths relative to the work dir)
    T = RECORD_S[N]
    g = f"N={N}"
    if "generate" in commands or not (d / "est.csv").exists():
        a.call(g, f"generate est ({T} s)", ["generate", "--zones", N, "--duration", T,
                                             "--out", p("est.csv"), "--quiet"], js=p("gen.json"))
        a.call(g, "generate val (seed 1)", ["generate", "--zones", N, "--duration", T,
                                            "--seed", 1, "--out", p("val.csv"), "--quiet"])
    if not (d / "est.csv").exists():
        return
    ts, lo, hi = csv_range(d / "est.csv")
    if "fit" in commands or not (d / "ss.jtm").exists():
        a.call(g, "fit ss (default order)", ["fit", p("est.csv"), "--model", "ss", "--validation",
                                             p("val.csv"), "--out", p("ss.jtm"), "--quiet"],
               js=p("fit_ss.json"), checks=[fits_in_range(50.0)], timeout=900)
    if "families" in commands and (N <= 3 or families_all):
        for fam in FAMILIES:
            a.call(g, f"fit {fam} (default orders)",
                   ["fit", p("est.csv"), "--model", fam, "--validation", p("val.csv"),
                    "--out", p(f"{fam}.jtm"), "--quiet"], js=p(f"fit_{fam}.json"),
                   checks=[fits_in_range(0.0)], timeout=900)
    if not (d / "ss.jtm").exists():
        return
    if "validate" in commands:
        a.call(g, "validate ss on val", ["validate", p("ss.jtm"), p("val.csv"), "--quiet"],
               js=p("val.json"), checks=[fits_in_range(50.0)])
    if "tune" in commands:
        for c in ("pi", "lqg"):
            a.call(g, f"tune {c} --model M (plant default)",
                   ["tune", "--controller", c, "--model", p("ss.jtm"), "--out", p(f"{c}.jtm"),
                    "--quiet"], js=p(f"tune_{c}.json"),
                   checks=[tuned_on_own_plant(ts, lo, hi)], timeout=900)
            if not (d / f"{c}.jtm").exists():
                a.call(g, f"tune {c} --model M --plant M",
                       ["tune", "--controller", c, "--model", p("ss.jtm"), "--plant", p("ss.jtm"),
                        "--out", p(f"{c}.jtm"), "--quiet"], js=p(f"tune_{c}_plant.json"),
                       checks=[tuned_on_own_plant(ts, lo, hi)], timeout=900)
    if "simulate" in commands:
        a.call(g, "simulate tracking pi on M", ["simulate", "--scenario", "tracking", "--controller",
                                               "pi", "--plant", p("ss.jtm"), "--quiet"],
               js=p("sim.json"))
        if (d / "pi.jtm").exists():
            a.call(g, "simulate tracking tuned pi file", ["simulate", "--scenario", "tracking",
                   "--controller-file", p("pi.jtm"), "--plant", p("ss.jtm"), "--quiet"],
                   js=p("sim_file.json"))
    if "export" in commands:
        for c in ("pi", "lqg"):
            if (d / f"{c}.jtm").exists():
                for to in ("c", "json"):
                    a.call(g, f"export {c} --to {to}", ["export", p(f"{c}.jtm"), "--to", to,
                                                        "--out", p(f"exp_{c}_{to}"), "--quiet"],
                           js=p(f"exp_{c}_{to}.json"))
    if "diagnose" in commands:
        a.call(g, "diagnose (plain bed)", ["diagnose", p("est.csv"), "--validation", p("val.csv"),
                                           "--quiet"], js=p("diag.json"), checks=[names_nothing],
               timeout=1200)
    if "sweep" in commands:
        cfg = d / "sweep.toml"
        cfg.write_text(f'[sweep]\nname = "audit-{N}"\nkind = "identify"\n[data]\n'
                       f'data = "{d / "est.csv"}"\nvalidation = "{d / "val.csv"}"\n'
                       '[space]\nfamily = ["arx"]\nna = [1, 2]\nnb = [1]\nnk = [1]\n')
        (d / "sweep.jsonl").unlink(missing_ok=True)
        a.call(g, "sweep identify arx (2 trials)", ["sweep", p("sweep.toml"), "--results",
                                                   p("sweep.jsonl"), "--quiet"],
               js=p("sweep.json"))


def cold_cases(a: Audit):
    """The first call of a user: an empty compilation cache (`JTHERMO_CACHE_DIR` a fresh
    directory), N = 2, every command once."""
    cache = Path(tempfile.mkdtemp(prefix="cold_cache_", dir=a.work))
    a.env = {**os.environ, "JTHERMO_CACHE_DIR": str(cache)}
    d = a.work / "cold"
    d.mkdir(exist_ok=True)
    g = "cold N=2"
    a.call(g, "generate est", ["generate", "--zones", 2, "--duration", 1800, "--out",
                               "cold/est.csv", "--quiet"])
    a.call(g, "generate val", ["generate", "--zones", 2, "--duration", 1800, "--seed", 1, "--out",
                               "cold/val.csv", "--quiet"])
    a.call(g, "fit ss", ["fit", "cold/est.csv", "--model", "ss", "--validation", "cold/val.csv",
                         "--out", "cold/ss.jtm", "--quiet"], js="cold/fit.json",
           checks=[fits_in_range(50.0)])
    a.call(g, "validate", ["validate", "cold/ss.jtm", "cold/val.csv", "--quiet"],
           js="cold/val.json", checks=[fits_in_range(50.0)])
    a.call(g, "tune pi", ["tune", "--controller", "pi", "--model", "cold/ss.jtm", "--out",
                          "cold/pi.jtm", "--quiet"], js="cold/tune.json")
    a.call(g, "simulate tuned pi", ["simulate", "--scenario", "tracking", "--controller-file",
                                    "cold/pi.jtm", "--plant", "cold/ss.jtm", "--quiet"],
           js="cold/sim.json")
    a.call(g, "diagnose", ["diagnose", "cold/est.csv", "--validation", "cold/val.csv", "--quiet"],
           js="cold/diag.json", checks=[names_nothing])
    a.env = None


def real_cases(a: Audit, commands):
    d = a.work / "real"
    d.mkdir(exist_ok=True)
    for label, est, val, tune, expect in REAL_CASES:
        slug = est.replace("/", "_")
        e = REAL / est / "data.csv"
        v = REAL / val / "data.csv" if val else e
        g = "real"
        ts, lo, hi = csv_range(e)
        m = f"real/{slug}.jtm"
        a.call(g, f"{label}: fit ss", ["fit", e, "--model", "ss", "--validation", v, "--out", m,
                                       "--quiet"], js=f"real/{slug}_fit.json",
               checks=[fits_in_range()], timeout=900, expect=expect)
        if expect != "ok":
            continue
        if (a.work / m).exists() and val:
            a.call(g, f"{label}: validate", ["validate", m, v, "--quiet"],
                   js=f"real/{slug}_val.json", checks=[fits_in_range()])
        if "families" in commands:
            a.call(g, f"{label}: fit arx", ["fit", e, "--model", "arx", "--validation", v,
                                            "--quiet"], js=f"real/{slug}_arx.json",
                   checks=[fits_in_range()], timeout=900)
        if tune and (a.work / m).exists():
            a.call(g, f"{label}: tune pi", ["tune", "--controller", "pi", "--model", m, "--plant", m,
                                            "--quiet"], js=f"real/{slug}_tune.json",
                   checks=[tuned_on_own_plant(ts, lo, hi)], timeout=900)
        if "diagnose" in commands and val and tune:
            a.call(g, f"{label}: diagnose", ["diagnose", e, "--validation", v, "--actuator",
                                             "resistive-pwm", "--quiet"],
                   js=f"real/{slug}_diag.json", timeout=1200)


def bad_cases(a: Audit):
    d = a.work / "bad"
    d.mkdir(exist_ok=True)
    import numpy as np
    rng = np.random.default_rng(0)
    T = 200
    t = np.arange(T, dtype=float)
    u = rng.random((T, 2)).round(3)
    y = 100 + np.cumsum(rng.normal(size=(T, 2)), 0).round(3)

    def write(name, header, rows):
        (d / name).write_text(",".join(header) + "\n" + "\n".join(",".join(map(str, r)) for r in rows) + "\n")
        return f"bad/{name}"

    H = ["t", "u_1", "u_2", "y_1", "y_2"]
    good = write("good.csv", H, np.column_stack([t, u, y]).tolist())
    rows = np.column_stack([t, u, y]).tolist()
    rows_nan = [list(r) for r in rows]
    rows_nan[50][3] = "nan"
    tj = t.copy()
    tj[100:] += 0.37
    tj[150:] *= 1.5
    files = {
        "malformed CSV (ragged row)": (write("ragged.csv", H, rows[:60] + [rows[60][:3]] + rows[61:]), "fields"),
        "NaN in an output": (write("nan.csv", H, rows_nan), "NaN"),
        "non-uniform time": (write("nonuniform.csv", H, np.column_stack([tj, u, y]).tolist()), "not uniform"),
        "too few samples (5)": (write("short.csv", H, rows[:5]), "samples"),
        "missing file": ("bad/nope.csv", "no such file"),
        "unknown column": (write("unknown.csv", ["t", "u_1", "u_2", "y_1", "temp"], rows), "unknown column"),
    }
    for what, (f, says) in files.items():
        a.call("bad", f"fit: {what}", ["fit", f, "--model", "ss", "--quiet"], expect=says)
    # a model for the mismatch cases
    a.call("bad", "(setup) fit arx on good", ["fit", good, "--model", "arx", "--orders", "1,1,1",
                                             "--out", "bad/m.jtm", "--quiet"])
    a.call("bad", "validate: NaN data", ["validate", "bad/m.jtm", files["NaN in an output"][0],
                                         "--quiet"], expect="NaN")
    const = np.column_stack([t, np.full((T, 2), 0.5), y]).tolist()
    cfile = write("constant.csv", H, const)
    for fam in ("ss", "arx", "oe", "greybox"):
        a.call("bad", f"fit {fam}: constant input", ["fit", cfile, "--model", fam, "--quiet"],
               expect="constant")
    a.call("bad", "diagnose: constant input", ["diagnose", cfile, "--validation", cfile, "--quiet"],
           expect="constant")
    flat_y = np.column_stack([t, u, np.full(T, 25.0), y[:, 1]]).tolist()
    fy = write("flat_output.csv", H, flat_y)
    for fam in ("arx", "oe"):
        a.call("bad", f"fit {fam}: constant output", ["fit", fy, "--model", fam, "--quiet"],
               expect="is constant")
    a.call("bad", "validate: constant output", ["validate", "bad/m.jtm", fy, "--quiet"],
           expect="is constant")
    a.call("bad", "diagnose: constant output", ["diagnose", good, "--validation", fy, "--quiet"],
           expect="is constant", js="bad/diag_flat.json")
    zero = np.column_stack([t, np.zeros((T, 2)), y]).tolist()
    a.call("bad", "fit ss: all-zero input", ["fit", write("zero.csv", H, zero), "--model", "ss",
                                             "--quiet"], expect="constant")
    for fam, orders, says in (("arx", "0,0,0", "no parameters"), ("arx", "1,1", "orders"),
                              ("ss", "0", "order"), ("ss", "500", "order"),
                              ("oe", "-1,1,1", "order"), ("arx", "a,b,c", "order"),
                              ("arx", "150,150,1", "order")):
        a.call("bad", f"fit {fam} --orders {orders}", ["fit", good, "--model", fam, "--orders",
                                                       orders, "--quiet"], expect=says)
    H1 = ["t", "u_1", "y_1"]
    one = write("one.csv", H1, np.column_stack([t, u[:, 0], y[:, 0]]).tolist())
    a.call("bad", "validate: model 2x2 on 1x1 data", ["validate", "bad/m.jtm", one, "--quiet"],
           expect="the model 2")
    a.call("bad", "validate: missing model", ["validate", "bad/none.jtm", good, "--quiet"],
           expect="no such file")
    a.call("bad", "validate: data file as model", ["validate", good, good, "--quiet"],
           expect="not a jthermo save file")
    a.call("bad", "tune: --setpoint count mismatch", ["tune", "--controller", "pi", "--model",
                                                     "bad/m.jtm", "--plant", "bad/m.jtm",
                                                     "--setpoint", "50,60,70", "--quiet"],
           expect="set")
    a.call("bad", "tune: set point out of reach", ["tune", "--controller", "pi", "--model",
                                                  "bad/m.jtm", "--plant", "bad/m.jtm",
                                                  "--setpoint", "5000", "--quiet"],
           expect="set point")
    a.call("bad", "simulate: model as controller file", ["simulate", "--scenario", "tracking",
                                                         "--controller-file", "bad/m.jtm",
                                                         "--plant", "bad/m.jtm", "--quiet"],
           expect="controller")
    a.call("bad", "export: model as controller", ["export", "bad/m.jtm", "--to", "c", "--out",
                                                  "bad/exp", "--quiet"], expect="controller")
    a.call("bad", "diagnose: zone mismatch est/val", ["diagnose", good, "--validation", one,
                                                      "--quiet"], expect="the estimation data has 2")
    a.call("bad", "fit: est/val column mismatch", ["fit", good, "--model", "arx", "--validation",
                                                   one, "--quiet"], expect="validation")
    slow = write("ts2.csv", H, np.column_stack([2 * t, u, y]).tolist())
    a.call("bad", "validate: model at Ts 1 s on data at 2 s", ["validate", "bad/m.jtm", slow,
                                                                 "--quiet"], expect="sample time",
           js="bad/val_ts2.json")
    a.call("bad", "(setup) fit arx 1x1", ["fit", one, "--model", "arx", "--orders", "1,1,1",
                                          "--out", "bad/m1.jtm", "--quiet"])
    a.call("bad", "(setup) tune pi on the 2x2 model", ["tune", "--controller", "pi", "--model",
                                                       "bad/m.jtm", "--plant", "bad/m.jtm",
                                                       "--steps", 2, "--rollouts", 2, "--out",
                                                       "bad/c2.jtm", "--quiet"])
    a.call("bad", "tune: validation plant 1x1, model 2x2", ["tune", "--controller", "pi", "--model",
                                                           "bad/m.jtm", "--validation-plant",
                                                           "bad/m1.jtm", "--quiet"],
           expect="output")
    a.call("bad", "simulate: 2-zone controller on 1-zone plant",
           ["simulate", "--scenario", "tracking", "--controller-file", "bad/c2.jtm", "--plant",
            "bad/m1.jtm", "--quiet"], expect="drives 2 zones")
    m_slow = "bad/m_ts2.jtm"
    a.call("bad", "(setup) fit arx at Ts 2 s", ["fit", slow, "--model", "arx", "--orders", "1,1,1",
                                                "--out", m_slow, "--quiet"])
    a.call("bad", "simulate: Ts-1 controller on a Ts-2 plant",
           ["simulate", "--scenario", "tracking", "--controller-file", "bad/c2.jtm", "--plant",
            m_slow, "--quiet"], expect="sample time", js="bad/sim_ts2.json")
    # a TCLab record with its heaters logged in % (0-100) instead of power fractions
    src = REAL / "tclab_cace2020" / "id_2heaters" / "data.csv"
    rec = np.loadtxt(src, delimiter=",", skiprows=1)
    rec[:, 1:3] *= 100.0
    pct = write("tclab_percent.csv", src.read_text().splitlines()[0].split(","), rec.tolist())
    a.call("bad", "(setup) fit ss 4 on TCLab inputs in %", ["fit", pct, "--model", "ss", "--orders",
                                                            4, "--out", "bad/pct.jtm", "--quiet"])
    a.call("bad", "simulate: plant recorded with inputs in %", ["simulate", "--scenario",
           "tracking", "--controller", "pi", "--plant", "bad/pct.jtm", "--quiet"],
           expect="rescale the inputs", js="bad/sim_pct.json")
    a.call("bad", "tune: plant recorded with inputs in %", ["tune", "--controller", "pi", "--model",
                                                            "bad/pct.jtm", "--quiet"],
           expect="rescale the inputs")
    (d / "bad.toml").write_text("[sweep]\nname = 1\nkind = 'nope'\n")
    a.call("bad", "sweep: bad config", ["sweep", "bad/bad.toml", "--quiet"], expect="name")
    a.call("bad", "simulate: 1-zone model, pi, --zones 3", ["simulate", "--scenario", "tracking",
                                                            "--controller", "pi", "--plant",
                                                            "bad/m.jtm", "--zones", "3", "--quiet"],
           expect="zones")


# ---------------------------------------------------------------- report


def markdown(rows, argv, total_cpu, total_wall, load, commit="", kept=0):
    n_fail = sum(not r["ok"] for r in rows)
    groups = {}
    for r in rows:
        g = groups.setdefault(r["group"], [0, 0, 0.0, 0.0])
        g[0] += 1
        g[1] += not r["ok"]
        g[2] += r["wall_s"]
        g[3] += r["cpu_s"]
    lines = ["# Default-path audit", "",
             f"`python experiments/default_path_audit.py {' '.join(argv)}`{commit} — {len(rows)} "
             f"CLI calls as subprocesses, {n_fail} failing a check; {total_wall:.0f} s wall, "
             f"{total_cpu:.0f} CPU s (children, user+sys), load average {load}"
             + (f" (the calls run now; {kept} rows of the groups not run now kept from the "
                "results before, `--keep-others`)" if kept else "") + ". Record lengths "
             f"(1 s samples): {RECORD_S}. Every group but `cold` runs with this machine's "
             "persistent compilation cache (warm where an earlier run compiled the same "
             "program); `cold` uses an empty one (`JTHERMO_CACHE_DIR`), a user's first calls.", "",
             "| group | calls | failing | wall s | CPU s |", "|---|---|---|---|---|"]
    lines += [f"| {g} | {v[0]} | {v[1]} | {v[2]:.0f} | {v[3]:.0f} |" for g, v in groups.items()]
    lines += ["", "| group | call | exit | wall s | CPU s | result | figures | stderr (last line) |",
              "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        res = "ok" if r["ok"] else "**FAIL**: " + "; ".join(r["problems"])
        err = r["stderr_last"].replace("|", "\\|")[:160]
        fig = "; ".join(f"{k} {v}" for k, v in (r.get("figures") or {}).items())
        lines.append(f"| {r['group']} | {r['name']} | {r['rc']} | {r['wall_s']} | {r['cpu_s']} | "
                     f"{res} | {fig} | {err} |")
    lines += ["", "Failing calls, with the command:", ""]
    for r in rows:
        if not r["ok"]:
            lines.append(f"- {r['group']} / {r['name']}: `{' '.join(r['argv'])}` — "
                         f"{'; '.join(r['problems'])}")
    return "\n".join(lines) + "\n"


def commit_note() -> str:
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, cwd=ROOT).stdout.strip()
    except OSError:
        return ""
    return f" at {rev}" if rev else ""


def relative(text: str) -> str:
    """Paths of this machine written relative to the repository (`../shared/...`)."""
    return text.replace(str(ROOT.parent) + "/", "../")


def render(path):
    """Write the Markdown table again from a results JSON (`--render`), its paths relative."""
    path = Path(path)
    res = json.loads(relative(path.read_text()))
    path.write_text(json.dumps(res, indent=1) + "\n")
    path.with_suffix(".md").write_text(markdown(res["rows"], res["argv"], res["cpu_s"],
                                                res["wall_s"], res["load"],
                                                res.get("commit", ""),
                                                res.get("kept_rows", 0)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--render", metavar="JSON", help="only rewrite the Markdown of a results JSON")
    ap.add_argument("--only", default="zones,real,bad,cold", help="parts: zones, real, bad, cold")
    ap.add_argument("--zones", default=",".join(map(str, ZONES)))
    ap.add_argument("--commands", default=",".join(COMMANDS))
    ap.add_argument("--families-all", action="store_true")
    ap.add_argument("--work", default=None, help="work directory (default: a temporary one)")
    ap.add_argument("--out", default=str(ROOT / "experiments" / "results"))
    ap.add_argument("--keep-others", action="store_true",
                    help="keep the rows of the groups not run now from the results JSON")
    ap.add_argument("--slack", type=float, default=1.0,
                    help="multiply every call's timeout (a shared, loaded machine)")
    args = ap.parse_args(argv)
    if args.render:
        return render(args.render)
    args.argv = sys.argv[1:] if argv is None else argv
    parts = set(args.only.split(","))
    commands = set(args.commands.split(","))
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="jthermo_audit_"))
    work.mkdir(parents=True, exist_ok=True)
    a = Audit(work)
    a.slack = args.slack
    t0 = time.perf_counter()
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    load0 = os.getloadavg()[0]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "default_path_audit"

    def write(partial: bool) -> tuple[float, float]:
        """The results so far (after every call, so that an audit cut short keeps them)."""
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
        wall = time.perf_counter() - t0
        load = f"{load0:.1f} -> {os.getloadavg()[0]:.1f}"
        note = commit_note() + (" (still running: the calls made so far)" if partial else "")
        (out / f"{stem}.json").write_text(relative(json.dumps(
            {"argv": args.argv, "rows": rows(), "kept_rows": len(rows()) - len(a.rows),
             "cpu_s": cpu, "wall_s": wall, "load": load,
             "commit": note}, indent=1)) + "\n")
        render(out / f"{stem}.json")
        return cpu, wall

    kept = []
    if args.keep_others:
        try:
            kept = json.loads((out / f"{stem}.json").read_text())["rows"]
        except (OSError, ValueError, KeyError):
            kept = []

    def rows():
        now = {r["group"] for r in a.rows}
        return [r for r in kept if r["group"] not in now and r["group"] not in running] + a.rows

    running = set()
    if "zones" in parts:
        running |= {f"N={N}" for N in map(int, args.zones.split(","))}
    if "bad" in parts:
        running.add("bad")
    if "cold" in parts:
        running.add("cold N=2")
    if "real" in parts:
        running.add("real")
    a.on_row = lambda: write(True)
    if "bad" in parts:
        bad_cases(a)
    if "zones" in parts:
        for N in map(int, args.zones.split(",")):
            zone_cases(a, N, commands, args.families_all)
    if "real" in parts:
        real_cases(a, commands)
    if "cold" in parts:
        cold_cases(a)
    cpu, wall = write(False)
    print(f"{sum(not r['ok'] for r in a.rows)} of {len(a.rows)} calls failing; {cpu:.0f} CPU s, "
          f"{wall:.0f} s wall; work dir {work}")


if __name__ == "__main__":
    main()
