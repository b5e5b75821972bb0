"""`jthermo tune` on the virtual printer at its own scale: every family at N zones with the
CLI's defaults, each run in its own process under a watchdog; `simulate` and `demo` beside.

Per run: exit status, wall time and CPU s of the child (user+sys), the improvement below the
lambda PI and below the best classical design on the held-out seed, and the Ms guard (the
chosen loop's peak sensitivity against its bound). `cold`: a fresh compilation cache
(`JTHERMO_CACHE_DIR`, which `runtime.default_cache_dir` reads first); `warm`: the same command
again on that cache. Each tune run is the command's own `main` in a child process whose
`progress.stage` blocks are timed (wall, compile, CPU of the process and of the stage's
thread): the results file shows where the slowest families' cold runs spend their time.

`--others simulate,demo`: those commands at 16 zones, cold then warm (`--warm`).

`--ab`: the two ways to keep `tune_report`'s two threads off a deadlock, compared on one
configuration: its threads with LAPACK one matrix at a time (`runtime.one_matrix_at_a_time`,
as shipped) against no second thread (its work run in turn on the main thread) with the
batched kernels; each cold then warm, in its own process.

Runs made side by side write their own files (`--out`); `--merge A.md,B.md` gathers their
rows into the results file (with `--resume`: the finished rows there are kept).

Usage:
    .venv/bin/python experiments/printer_scale.py [--zones 16,9,19]
        [--families pi,pi_ff,lqg,lqg_ff] [--warm] [--limit 1500]
        [--others simulate,demo] [--ab [--ab-steps 10]] [--zones ''] (`--zones ''`: no tune
        runs) [--resume] [--out FILE] [--merge FILES]
Writes `experiments/results/printer_scale.md` (overwritten after every run, so a run cut short
keeps what it measured).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "results" / "printer_scale.md"
JTHERMO = [sys.executable, "-m", "jthermo.cli"]

AB_CHILD = r"""
import json, os, sys, time
from concurrent.futures import Future
import jax
jax.config.update("jax_enable_x64", True)
from jthermo import runtime
runtime.enable_cache(); runtime.unroll_threefry()
import jthermo.tune.report as R
mode, steps = sys.argv[1], int(sys.argv[2])
if mode == "serial":            # no second thread, batched LAPACK kernels
    R.one_matrix_at_a_time = lambda: False

    class InOrder:
        def __init__(self, *a, **k): pass
        def __enter__(self): return self
        def __exit__(self, *a): pass
        def submit(self, fn, *a, **k):
            f = Future(); f.set_result(fn(*a, **k)); return f

    R.ThreadPoolExecutor = InOrder
t0, c0 = time.time(), time.process_time()
rep = R.tune_report("lqg", plant="printer", zones=16, steps=steps, rollouts=16, seed=11, lr=0.1)
print(json.dumps({"wall": time.time() - t0, "cpu": time.process_time() - c0,
                  "improvement": rep["improvement_percent"]}))
"""


PROFILE_CHILD = r"""
import contextlib, json, sys, threading, time
from jthermo import progress, runtime
import jthermo.cli as cli
import jthermo.tune.report, jthermo.tune.training, jthermo.tune.own   # noqa: F401
orig, rec = progress.stage, []


@contextlib.contextmanager
def stage(name):
    t0, c0, h0 = time.time(), time.process_time(), time.thread_time()
    with orig(name):
        try:
            yield
        finally:
            rec.append({"thread": threading.current_thread().name, "stage": str(name),
                        "t0": t0, "t1": time.time(), "cpu": time.process_time() - c0,
                        "thread_cpu": time.thread_time() - h0})


for mod in list(sys.modules.values()):
    if getattr(mod, "__name__", "").startswith("jthermo") and getattr(mod, "stage", None) is orig:
        mod.stage = stage
progress.stage = stage
runtime._listen()
t0, c0 = time.time(), time.process_time()
rc = cli.main(sys.argv[1:])
t1 = time.time()
with runtime._lock:
    spans = list(runtime._spans)
for r in rec:
    r["compile_s"] = runtime.union_seconds(spans, r["t0"], r["t1"])
    r["wall"] = r["t1"] - r["t0"]
    r["start"] = r.pop("t0") - t0
    r.pop("t1")
print(json.dumps({"rc": rc, "wall": t1 - t0, "cpu": time.process_time() - c0,
                  "compile_s": runtime.union_seconds(spans, t0, t1), "stages": rec}))
"""


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(argv, env, limit):
    c0, t0 = _children_cpu(), time.perf_counter()
    try:
        p = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=limit, cwd=ROOT)
        rc, err = p.returncode, p.stderr
    except subprocess.TimeoutExpired as exc:
        rc, err = "timeout", (exc.stderr or b"").decode() if isinstance(exc.stderr, bytes) \
            else (exc.stderr or "")
    last = next((ln for ln in reversed(err.strip().splitlines()) if ln.strip()), "")
    return rc, time.perf_counter() - t0, _children_cpu() - c0, last, p.stdout if rc == 0 else ""


def tune_row(family, zones, cache, limit, label):
    """`jthermo tune` of `family` at `zones` in its own process (`PROFILE_CHILD`: the command's
    `main` with its stages timed), its report's figures and where its time went."""
    js = Path(tempfile.mkdtemp(prefix="jthermo-scale-")) / "t.json"
    env = {**os.environ, "JTHERMO_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
    argv = ["tune", "--controller", family, "--plant", "printer", "--zones", str(zones),
            "--seed", "11", "--json", str(js), "--quiet"]
    rc, wall, cpu, last, out = _run([sys.executable, "-c", PROFILE_CHILD, *argv], env, limit)
    row = {"family": family, "zones": zones, "cache": label, "rc": rc, "wall_s": wall,
           "cpu_s": cpu, "stderr": last}
    if rc == 0 and out.strip():
        prof = json.loads(out.strip().splitlines()[-1])
        rc = row["rc"] = prof["rc"]
        row["profile"] = {"command": "jthermo " + " ".join(argv[:-3]),
                          "cache": label, **prof}
    if rc == 0 and js.exists():
        r = json.loads(js.read_text())
        ms = r.get("ms_constraint") or {}
        row.update(vs_lambda=r.get("improvement_percent"),
                   vs_best=r.get("improvement_vs_best_classical_percent"),
                   best=r.get("best_classical"), ms=ms.get("chosen_ms"),
                   ms_max=ms.get("ms_max"), ms_ok=ms.get("satisfied"),
                   steps=r.get("steps"), compile_s=r.get("compile_s"))
    return row


#: the families whose finished cold runs' stages the results file shows
PROFILED = ("pi", "pi_ff", "lqg", "lqg_ff")
#: the other commands at the printer's scale (`--others`): argv after `jthermo`
OTHERS = {"simulate": ["simulate", "--scenario", "print", "--controller", "pi_lambda",
                       "--zones", "16", "--rollouts", "64"],
          "demo": ["demo", "--zones", "16"]}


def _scalars(rep: dict, prefix="", depth=2) -> dict:
    """The report's numbers and short strings, flattened (`a.b`), for the table."""
    out = {}
    for k, v in rep.items():
        if isinstance(v, (bool, int, float)) or (isinstance(v, str) and len(v) < 40):
            out[prefix + k] = v
        elif isinstance(v, dict) and depth > 1:
            out.update(_scalars(v, f"{prefix}{k}.", depth - 1))
    return out


def other_row(name, cache, label, limit):
    """One of `OTHERS` in its own process: exit, wall, CPU, last stderr line, a few figures."""
    work = Path(tempfile.mkdtemp(prefix="jthermo-scale-"))
    env = {**os.environ, "JTHERMO_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
    argv = [*OTHERS[name], "--json", str(work / "r.json"), "--quiet"]
    if name == "demo":
        argv += ["--runs-dir", str(work / "runs")]
    rc, wall, cpu, last, _ = _run(JTHERMO + argv, env, limit)
    row = {"command": "jthermo " + " ".join(OTHERS[name]), "cache": label, "rc": rc,
           "wall_s": wall, "cpu_s": cpu, "stderr": last}
    if rc == 0 and (work / "r.json").exists():
        sc = _scalars(json.loads((work / "r.json").read_text()))
        row["figures"] = {k: v for k, v in sc.items()
                          if any(w in k for w in ("error", "mse", "cost", "percent", "zones",
                                                  "rollouts", "seconds", "compile_s", "ready",
                                                  "overshoot"))}
    return row


def _f(v, nd=1):
    return "-" if v is None else (f"{v:.{nd}f}" if isinstance(v, float) else str(v))


def render_profile(prof: list) -> list[str]:
    """The stages of profiled runs (`--profile`): where a command's time goes."""
    lines = []
    for p in prof:
        lines += ["", f"## Where the time goes: `{p['command']}` ({p['cache']})", "",
                  "In one process (the command's `main` with its stages timed), measured on a "
                  f"shared, loaded machine (load "
                  f"{p.get('load', '?')}): {p['wall']:.0f} s wall, {p['cpu']:.0f} CPU s, of "
                  f"which compiling (JAX's trace, lower and compile events, both threads) "
                  f"{p['compile_s']:.0f} s wall. Per stage of each thread (`progress.stage`, "
                  "nested stages inside their parent's time): wall s, compile s (of any thread "
                  "meanwhile), CPU s of the process meanwhile (both threads and XLA's), CPU s of "
                  "the stage's own thread.", "",
                  "| thread | stage | starts at s | wall s | compile s | process CPU s | "
                  "thread CPU s |", "|---|---|---|---|---|---|---|"]
        for r in sorted(p["stages"], key=lambda r: r["start"]):
            if r["wall"] < 0.5:
                continue
            lines.append(f"| {r['thread']} | {r['stage']} | {r['start']:.0f} | "
                         f"{r['wall']:.1f} | {r['compile_s']:.1f} | {r['cpu']:.1f} | "
                         f"{r['thread_cpu']:.1f} |")
    return lines


def render_others(others: list) -> list[str]:
    if not others:
        return []
    lines = ["", "## `simulate` and `demo` at 16 zones", "",
             "Each in its own process (`--others`); figures: the report's numbers (`--json`).", "",
             "| command | cache | exit | wall s | CPU s | report |", "|---|---|---|---|---|---|"]
    for r in others:
        fig = "; ".join(f"{k} {_f(v, 3)}" for k, v in (r.get("figures") or {}).items())
        res = fig if r["rc"] == 0 else f"`{r['stderr'][:200]}`"
        lines.append(f"| `{r['command']}` | {r['cache']} | {r['rc']} | {_f(r['wall_s'], 0)} | "
                     f"{_f(r['cpu_s'], 0)} | {res} |")
    return lines


def render(rows, ab, load, prof=(), others=()) -> str:
    zones = ", ".join(str(z) for z in sorted({r["zones"] for r in rows})) or "no"
    lines = [f"# `jthermo tune` on the virtual printer at its scale ({zones} zones measured)", "",
             "Measured on a 2-core machine, shared with other jobs for some rows (a row's load: the "
             "1-minute load average at the end of its run; a load near 2 or below is a quiet "
             f"machine; all: {load}): wall times under load are upper bounds, CPU s (user+sys of the child) the "
             "steadier figure. On an idle 2-core machine a run's wall time is at most its CPU "
             "s (some thread of it is always running: it waits on nothing but the CPU, the "
             "cache's files aside) and at least half of it (two cores); CPU s measured under "
             "load are themselves an upper bound (XLA's pool threads spin when descheduled). "
             "Seed 11, CLI defaults otherwise; `cold` on an empty compilation cache "
             "(`JTHERMO_CACHE_DIR` a fresh directory), `warm` on that cache again.", "",
             "Reproduce: `python experiments/printer_scale.py --zones 16,9,19 --warm` "
             "(`--others simulate,demo --warm` for the `simulate`/`demo` table, `--ab` for "
             "the threads table); each row's command is `jthermo tune --controller FAMILY "
             "--plant printer --zones N --seed 11`.", "",
             "| command | cache | exit | wall s | CPU s | load | below lambda PI % | "
             "below best classical % (best) | Ms (bound, ok) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["zones"] != 16, r["zones"], r["family"],
                                         r["cache"])):
        ms = "-" if r.get("ms") is None else \
            f"{r['ms']:.2f} ({_f(r.get('ms_max'), 1)}, {r.get('ms_ok')})"
        cmd = f"`tune --controller {r['family']} --zones {r['zones']}`"
        lines.append(f"| {cmd} | {r['cache']} | {r['rc']} | "
                     f"{_f(r['wall_s'], 0)} | {_f(r['cpu_s'], 0)} | {r.get('load', '?')} | "
                     f"{_f(r.get('vs_lambda'))} | "
                     f"{_f(r.get('vs_best'))} ({r.get('best', '-')}) | {ms} |")
    bad = [r for r in rows if r["rc"] != 0]
    if bad:
        lines += ["", "Exit `timeout`: the run reached this script's `--limit` (wall) and was "
                  "killed; `-15`: stopped by hand (SIGTERM) when the study's time was up. Both "
                  "while still using CPU (the CPU s it had used is in its row): not a hang of "
                  "the command, whose own watchdog (`--timeout`, 1200 s without progress) "
                  "never fired; no figures."]
    for r in bad:
        lines.append(f"\n{r['family']} at {r['zones']} zones ({r['cache']}): exit {r['rc']}, "
                     f"last stderr line: `{r['stderr'][:300]}`")
    if ab:
        lines += ["", "## Two threads with LAPACK one matrix at a time, or one thread", "",
                  "`tune_report('lqg', zones=16, rollouts=16, steps=10, seed=11, lr=0.1)` "
                  "(`--ab-steps`) in its own process: `threads` as shipped (`runtime.one_matrix_at_a_time`), `serial` "
                  "the second thread's work run in turn on the main thread with the batched "
                  "kernels. Same improvement in every run (bit-equal reports).", "",
                  "| variant | cache | wall s | CPU s | below lambda PI % |",
                  "|---|---|---|---|---|"]
        for r in ab:
            lines.append(f"| {r['variant']} | {r['cache']} | {_f(r.get('wall'), 0)} | "
                         f"{_f(r.get('cpu'), 0)} | {_f(r.get('improvement'), 3)} |")
    lines += render_others(list(others))
    lines += render_profile([{**r["profile"], "load": r.get("load", "?"),
                              "command": f"jthermo tune --controller {r['family']} --plant "
                                         f"printer --zones {r['zones']} --seed 11"}
                             for r in rows if r.get("profile") and r["family"] in PROFILED
                             and r["cache"] != "warm"] + list(prof))
    blob = {"rows": rows, "ab": ab, "profile": list(prof), "others": list(others)}
    lines += ["", f"<!-- rows (read back by --resume): {json.dumps(blob)} -->"]
    return "\n".join(lines) + "\n"


def _resumed(path: Path = OUT, finished: bool = True) -> tuple[list, list, list, list]:
    """The rows, A/B runs and profiles recorded in a results file (`--resume`, `--merge`), else
    empty lists."""
    try:
        text = path.read_text()
        blob = text.rsplit("<!-- rows (read back by --resume): ", 1)[1].rsplit(" -->", 1)[0]
        got = json.loads(blob)
        return ([r for r in got["rows"] if r.get("rc") == 0 or not finished], got["ab"],
                got.get("profile", []), got.get("others", []))
    except (OSError, IndexError, ValueError, KeyError):
        return [], [], [], []


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zones", default="16,9,19")
    ap.add_argument("--families", default="pi,pi_ff,lqg,lqg_ff")
    ap.add_argument("--warm", action="store_true")
    ap.add_argument("--limit", type=float, default=1500.0, help="seconds per run")
    ap.add_argument("--ab", action="store_true")
    ap.add_argument("--ab-steps", type=int, default=10)
    ap.add_argument("--profile", default="",
                    help="FAMILY: profile `tune` of FAMILY at the first --zones (cold, then "
                         "warm with --warm), stage by stage, in one process")
    ap.add_argument("--others", default="",
                    help="comma-separated: simulate, demo (cold, then warm with --warm), "
                         "instead of the tune runs")
    ap.add_argument("--cache", default="",
                    help="run on this compilation cache (as it is), not a fresh one per family")
    ap.add_argument("--label", default="",
                    help="the cache column of these runs (with --cache; default `warm`)")
    ap.add_argument("--out", default=str(OUT), help="results file (default %(default)s)")
    ap.add_argument("--merge", default="",
                    help="comma-separated results files of runs made meanwhile: their rows too")
    ap.add_argument("--resume", action="store_true",
                    help="keep the finished runs of the results file, run only the others")
    a = ap.parse_args()
    out_path = Path(a.out)
    rows, ab, prof, others = _resumed(out_path) if a.resume else ([], [], [], [])
    for other in filter(None, a.merge.split(",")):
        r2, ab2, p2, o2 = _resumed(Path(other), finished=False)
        others = [o for o in others if o["command"] not in {q["command"] for q in o2}] + o2
        keys = {(r["family"], r["zones"], r["cache"]) for r in r2}
        rows = [r for r in rows if (r["family"], r["zones"], r["cache"]) not in keys] + r2
        ab, prof = ab or ab2, [p for p in prof if p["command"] not in
                               {q["command"] for q in p2}] + p2
    done = {(r["family"], r["zones"], r["cache"]) for r in rows}
    load = lambda: f"{os.getloadavg()[0]:.1f}"   # noqa: E731
    loads = [str(r.get("load", "?")) for r in rows]
    if a.others:
        for name in a.others.split(","):
            cache = Path(tempfile.mkdtemp(prefix="jthermo-scale-cache-"))
            others = [o for o in others if o["command"] != "jthermo " + " ".join(OTHERS[name])]
            for label in ("cold", "warm") if a.warm else ("cold",):
                others.append({**other_row(name, cache, label, a.limit), "load": load()})
                loads.append(load())
                out_path.write_text(render(rows, ab, " ".join(loads), prof, others))
                print(json.dumps(others[-1]), flush=True)
        return
    if a.profile:
        zones = int(a.zones.split(",")[0])
        cache = Path(tempfile.mkdtemp(prefix="jthermo-profile-"))
        env = {**os.environ, "JTHERMO_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
        args = ["tune", "--controller", a.profile, "--plant", "printer", "--zones", str(zones),
                "--seed", "11", "--quiet"]
        prof = [p for p in prof if p["command"] != "jthermo " + " ".join(args)]
        for label in ("cold", "warm") if a.warm else ("cold",):
            rc, *_, out = _run([sys.executable, "-c", PROFILE_CHILD, *args], env, a.limit)
            if rc == 0:
                prof.append({"command": "jthermo " + " ".join(args), "cache": label,
                             "load": load(), **json.loads(out.strip().splitlines()[-1])})
            loads.append(load())
            out_path.write_text(render(rows, ab, " ".join(loads), prof, others))
        return
    for zones in (int(z) for z in a.zones.split(",") if z):
        for family in a.families.split(","):
            cache = Path(a.cache) if a.cache else \
                Path(tempfile.mkdtemp(prefix="jthermo-scale-cache-"))
            labels = ("cold", "warm") if a.warm else ("cold",)
            for label in (a.label or "warm",) if a.cache else labels:
                if (family, zones, label) in done:
                    continue
                rows.append({**tune_row(family, zones, cache, a.limit, label), "load": load()})
                loads.append(load())
                out_path.write_text(render(rows, ab, " ".join(loads), prof, others))
                print(json.dumps(rows[-1]), flush=True)
    if a.ab and not ab:
        for variant in ("serial", "threads"):
            cache = Path(tempfile.mkdtemp(prefix="jthermo-ab-"))
            env = {**os.environ, "JTHERMO_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
            for label in ("cold", "warm"):
                rc, *_, out = _run([sys.executable, "-c", AB_CHILD, variant, str(a.ab_steps)],
                                   env, a.limit)
                rec = json.loads(out.strip().splitlines()[-1]) if rc == 0 else {}
                ab.append({"variant": variant, "cache": label, **rec})
                loads.append(load())
                out_path.write_text(render(rows, ab, " ".join(loads), prof, others))
    out_path.write_text(render(rows, ab, " ".join(loads), prof, others))


if __name__ == "__main__":
    main()
