"""Latency of the `jthermo` command from the shell: cold (empty compilation cache) and warm (a
second process with the cache the first one filled), wall clock, compilation included.

Each command runs as its own process (`python -m jthermo.cli ...`) with `JTHERMO_CACHE_DIR`
set to a fresh temporary directory: run 1 is cold, run 2 warm. The wall time is measured
around the process; `compile_s` / `run_s` come from the command's `--json` report
(`jthermo.runtime.Stopwatch`). The load average (`/proc/loadavg`) is recorded next to each run:
on a shared machine every figure is inflated by the load.

    python benchmarks/latency.py                      # every command
    python benchmarks/latency.py --only simulate,diagnose
    python benchmarks/latency.py --no-cache-baseline  # add a run with --no-cache

Rows of earlier runs stay in `benchmarks/results/latency.json` unless re-measured; the
Markdown table `benchmarks/results/latency.md` is written from all rows.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import loads  # noqa: E402

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"

#: name -> (argv after `jthermo`, goal cold s, goal warm s)
COMMANDS = {
    "simulate": (["simulate", "--scenario", "tracking", "--controller", "pi", "--zones", "16",
                  "--rollouts", "256", "--duration", "3600"], 5, 2),
    "tune_pi": (["tune", "--controller", "pi"], 30, 30),
    "tune_lqg": (["tune", "--controller", "lqg"], 30, 30),
    "diagnose": (["diagnose", "{est}", "--validation", "{val}"], 20, 10),
    "demo": (["demo", "--runs-dir", "{tmp}/runs"], 90, 90),
}

#: the one-hour 4-zone record `diagnose` reads (and 30 min of validation data)
RECORD = ["--experiment", "prbs", "--zones", "4", "--effects",
          "lateral_conduction,radiative_loss,heater_lag"]



def _child_cpu() -> float:
    """User + system CPU seconds of the finished child processes so far."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def _jthermo(argv: list[str], env: dict, json_path: Path | None, cwd: str | None = None) -> dict:
    cmd = [sys.executable, "-m", "jthermo.cli", *argv, "--quiet"]
    if json_path is not None:
        cmd += ["--json", str(json_path)]
    load0 = loads()
    cpu0 = _child_cpu()
    t0 = time.perf_counter()
    r = subprocess.run(cmd, check=False, env=env, capture_output=True, text=True, cwd=cwd)
    wall = time.perf_counter() - t0
    row = {"wall_s": round(wall, 2), "cpu_s": round(_child_cpu() - cpu0, 2), "load_before": load0,
           "load_after": loads(), "returncode": r.returncode}
    if r.returncode != 0:
        row["error"] = (r.stderr.strip().splitlines() or ["?"])[-1]
        return row
    if json_path is not None and json_path.exists():
        rep = json.loads(json_path.read_text())
        for k in ("seconds", "compile_s", "run_s", "improvement_percent", "tuned_cost",
                  "start_cost", "verdict"):
            if k in rep:
                row[k] = rep[k]
        if "metrics" in rep:
            row["mse"] = rep["metrics"].get("mse")
        if rep.get("findings"):
            row["top_finding"] = rep["findings"][0].get("mechanism")
    return row


def measure(name: str, tmp: Path, no_cache_baseline: bool) -> dict:
    argv, goal_cold, goal_warm = COMMANDS[name]
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env.pop("JTHERMO_NO_CACHE", None)
    env["JTHERMO_CACHE_DIR"] = str(tmp / f"cache-{name}")
    fill = {"tmp": str(tmp), "est": str(tmp / "est.csv"), "val": str(tmp / "val.csv")}
    if name == "diagnose" and not (tmp / "est.csv").exists():
        data_env = dict(env, JTHERMO_NO_CACHE="1")
        for out, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
            _jthermo(["generate", *RECORD, "--duration", dur, "--seed", seed,
                      "--out", str(tmp / out)], data_env, None, str(tmp))
    argv = [a.format(**fill) for a in argv]
    row: dict = {"command": "jthermo " + " ".join(argv).replace(str(tmp), "TMP"),
                 "goal_cold_s": goal_cold, "goal_warm_s": goal_warm}
    # run in `tmp`: `python -m` puts its working directory first on the import path, so from a
    # checkout's root that checkout's `jthermo` would shadow a tree given on `PYTHONPATH`
    for phase in ("cold", "warm"):
        row[phase] = _jthermo(argv, env, tmp / f"{name}-{phase}.json", str(tmp))
        print(name, phase, row[phase], flush=True)
    if no_cache_baseline:
        row["no_cache"] = _jthermo(argv + ["--no-cache"], env, tmp / f"{name}-nc.json", str(tmp))
        print(name, "no-cache", row["no_cache"], flush=True)
    return row


def _cell(run: dict | None) -> str:
    if not run:
        return "—"
    if run.get("returncode"):
        return f"failed: {run.get('error', '')}"
    cpu = f" CPU {run['cpu_s']:.1f}" if "cpu_s" in run else ""
    return (f"{run['wall_s']:.1f} ({run.get('compile_s', float('nan')):.1f} / "
            f"{run.get('run_s', float('nan')):.1f}){cpu} load {run['load_before'].split()[0]}")


def _result(row: dict) -> str:
    w = row.get("warm") or {}
    if "improvement_percent" in w:
        return f"held-out improvement {w['improvement_percent']:.1f} %"
    if "verdict" in w:
        return f"{w['verdict']}" + (f", {w['top_finding']}" if w.get("top_finding") else "")
    if w.get("mse") is not None:
        return f"mse {w['mse']:.4g}"
    return ""


def write(rows: dict, meta: dict) -> None:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "latency.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    lines = ["# Latency of the jthermo command (wall clock from the shell)", "",
             ("`python benchmarks/latency.py`: each command in a fresh process, cold = empty "
             "compilation cache (a new temporary `JTHERMO_CACHE_DIR`), warm = a second process "
             "with the cache the first one filled. Cells: wall s (compile s / run s from the "
             "command's `--json`), the process's CPU s (user + system, all threads; rows "
             "measured before it was recorded have none) and the 1-minute load average when "
             "it started."), "",
             (f"Machine: {meta['machine']}, {meta['cpus']} CPUs shared with other jobs; "
             "wall times scale with the load (2 cores: a load of 10 makes everything ~5× slower)."), "",
             "| command | goal cold / warm s | cold | warm | --no-cache | result (warm run) |",
             "|---|---|---|---|---|---|"]
    for r in rows.values():
        lines.append(f"| `{r['command']}` | {r['goal_cold_s']} / {r['goal_warm_s']} | "
                     f"{_cell(r.get('cold'))} | {_cell(r.get('warm'))} | "
                     f"{_cell(r.get('no_cache'))} | {_result(r)} |")
    (RESULTS / "latency.md").write_text("\n".join(lines) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(COMMANDS),
                    help="comma-separated subset of " + ", ".join(COMMANDS))
    ap.add_argument("--no-cache-baseline", action="store_true")
    args = ap.parse_args()
    names = [n.strip() for n in args.only.split(",") if n.strip()]
    bad = [n for n in names if n not in COMMANDS]
    if bad:
        ap.error(f"unknown command(s) {bad}; choose from {list(COMMANDS)}")
    old = RESULTS / "latency.json"
    rows = json.loads(old.read_text())["rows"] if old.exists() else {}
    meta = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "python": platform.python_version()}
    # the package's bytecode as `make` leaves it (`compileall` at install): a shell with
    # PYTHONDONTWRITEBYTECODE would otherwise compile every changed module in every process
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(HERE.parent / "jthermo")], check=True)
    with tempfile.TemporaryDirectory(prefix="jthermo-latency-") as d:
        for n in names:
            rows[n] = measure(n, Path(d), args.no_cache_baseline)
            write(rows, meta)
    print((RESULTS / "latency.md").read_text())


if __name__ == "__main__":
    main()
