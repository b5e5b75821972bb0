"""Where `jthermo diagnose` spends its time: CPU seconds, wall seconds and compiles per stage.

The latency record of `benchmarks/latency.py` (one hour, 4 zones, PRBS, lateral conduction +
radiation + heater lag; 30 min of validation data) is diagnosed in a fresh process twice: cold
(empty compilation cache) and warm (a second process with the cache the first one filled). In
each process every call of the diagnosis's compiled fits (`fit_zones`, `sim_zones`,
`fit_joint`, `fit_records`) is timed (blocked until ready) and attributed to the stage it runs
in; the joint combination stage is split per `joint.JointFits.fit` call (one call per forward
selection round, plus the level test's). Compile time and count come from JAX's monitoring
events (tracing, lowering, backend compile; a cache hit counts as a short load). CPU seconds are
the process's user + system time (all threads): the load-robust figure on a shared machine.

    python benchmarks/diagnose_profile.py                 # cold + warm, writes the results
    python benchmarks/diagnose_profile.py --cprofile      # + the top functions (cold run)
    python benchmarks/diagnose_profile.py --zones 16 --phases cold   # the printer's scale

Writes `benchmarks/results/diagnose_profile.md` and `.json`.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import cpu_seconds, load1  # noqa: E402

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
#: the latency benchmark's record (benchmarks/latency.py RECORD) but its zone count, `--zones`
RECORD = ["--experiment", "prbs", "--effects",
          "lateral_conduction,radiative_loss,heater_lag"]


def write_record(tmp: Path, zones: int = 4) -> tuple[Path, Path]:
    """The latency record (`RECORD`: 1 h estimation, seed 1; 30 min validation, seed 2), at
    `zones` zones, written by `jthermo generate` to `tmp/est.csv`, `tmp/val.csv`; returns the
    two paths."""
    env = dict(os.environ, JTHERMO_NO_CACHE="1")
    for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
        subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", *RECORD, "--zones", str(zones),
                        "--duration", dur, "--seed", seed, "--out", str(tmp / name), "--quiet"],
                       check=True, env=env)
    return tmp / "est.csv", tmp / "val.csv"



class _Clock:
    """Wall, CPU and compile (seconds, backend compile count) accumulated per label."""

    def __init__(self):
        self.rows: dict[str, dict] = {}
        self.compile_s = 0.0
        self.compiles = 0
        self.loads = 0
        self.by_event: dict[str, float] = {}

    def on_duration(self, event: str, secs: float, **_):
        if event.startswith("/jax/core/compile/"):
            key = event.rsplit("/", 1)[1]
            self.by_event[key] = self.by_event.get(key, 0.0) + secs
        if event == "/jax/core/compile/backend_compile_duration":
            self.compiles += 1
            self.compile_s += secs
        elif event in ("/jax/core/compile/jaxpr_trace_duration",
                       "/jax/core/compile/jaxpr_to_mlir_module_duration"):
            self.compile_s += secs

    def on_event(self, event: str, **_):
        if event == "/jax/compilation_cache/cache_hits":
            self.loads += 1

    def snap(self):
        return time.perf_counter(), cpu_seconds(), self.compile_s, self.compiles, self.loads

    def add(self, label: str, s0, calls: int = 1):
        s1 = self.snap()
        r = self.rows.setdefault(label, {"wall_s": 0.0, "cpu_s": 0.0, "compile_s": 0.0,
                                         "compiles": 0, "cache_loads": 0, "calls": 0})
        for k, i in (("wall_s", 0), ("cpu_s", 1), ("compile_s", 2), ("compiles", 3), ("cache_loads", 4)):
            r[k] += s1[i] - s0[i]
        r["calls"] += calls


def _instrument(clock: _Clock, state: dict):
    """Time every compiled fit `select` calls, and each `joint.JointFits.fit` call."""
    import jax

    from jthermo.diagnose import candidates, commondrift, joint, select, validation

    def timed(name, fn):
        def wrapper(*a, **k):
            s0 = clock.snap()
            out = jax.block_until_ready(fn(*a, **k))
            clock.add(f"{state['stage']}: {name}", s0)
            return out
        return wrapper

    # each compiled fit as the stage modules import it (`diagnose.fitting`'s functions)
    for mod in (select, candidates, validation, joint, commondrift):
        for name in ("fit_zones", "sim_zones", "fit_joint", "fit_records"):
            if hasattr(mod, name):
                setattr(mod, name, timed(name, getattr(mod, name)))
    jf = joint.JointFits.fit

    def joint_fit(self, models, validate, **kw):
        state["round"] += 1
        outer = state["stage"]
        state["stage"] = f"joint call {state['round']} ({len(models)} models)"
        s0 = clock.snap()
        try:
            return jf(self, models, validate, **kw)
        finally:
            clock.add(state["stage"] + ": total", s0)
            state["stage"] = outer

    joint.JointFits.fit = joint_fit


def run_once(est_path: str, val_path: str, cprofile_out: str | None, one_thread: bool = False) -> dict:
    """Diagnose the record in this process; the per-stage table as a dict. `one_thread`: JAX's
    CPU backend with one intra-op thread (`runtime.one_thread_backend`)."""
    import jax
    import jax.monitoring

    from jthermo import runtime

    if one_thread:
        runtime.one_thread_backend()

    runtime.enable_cache()
    runtime.unroll_threefry()
    jax.config.update("jax_enable_x64", True)
    clock = _Clock()
    jax.monitoring.register_event_duration_secs_listener(clock.on_duration)
    jax.monitoring.register_event_listener(clock.on_event)
    state = {"stage": "baseline", "round": 0}
    t0, c0 = time.perf_counter(), cpu_seconds()
    s0 = clock.snap()
    import jthermo.diagnose as diag
    from jthermo.data import load

    est, val = load(est_path), load(val_path)
    clock.add("reading (import + load)", s0)
    _instrument(clock, state)
    order = ["baseline", "localisation", "candidates", "validation", "combination", "done"]
    marks = {"s": clock.snap()}

    def progress(i, total, info):
        clock.add(f"stage {info['stage']}", marks["s"])
        nxt = order.index(info["stage"]) + 1
        state["stage"] = order[nxt] if nxt < len(order) else "after"
        marks["s"] = clock.snap()

    prof = cProfile.Profile() if cprofile_out else None
    if prof:
        prof.enable()
    result = diag.diagnose(est, val, progress=progress)
    if prof:
        prof.disable()
        buf = io.StringIO()
        pstats.Stats(prof, stream=buf).sort_stats("cumulative").print_stats(40)
        Path(cprofile_out).write_text(buf.getvalue().replace(str(HERE.parent) + "/", ""))
    s0 = clock.snap()
    js = diag.to_json(result)
    json.dumps(js, default=float)
    clock.add("report (to_json)", s0)
    return {"rows": clock.rows, "total_wall_s": time.perf_counter() - t0, "total_cpu_s": cpu_seconds() - c0,
            "compile_s": clock.compile_s, "compiles": clock.compiles, "cache_loads": clock.loads,
            "compile_by_event": clock.by_event,
            "verdict": js["verdict"], "findings": [f["mechanism"] for f in js["findings"]],
            "augmented": js["augmented"]["mechanisms"],
            "baseline_fit": js["baseline"]["mean_fit_percent"],
            "augmented_fit": js["augmented"]["mean_fit_percent"],
            "augmented_fit_per_zone": js["augmented"]["fit_percent"],
            "parameters": js["augmented"]["parameters"],
            "findings_detail": js["findings"],
            "combinations": [{k: c[k] for k in ("mechanisms", "accepted", "mean_fit_percent")}
                             for c in js["combinations"]]}


def _subprocess(phase: str, est: Path, val: Path, cache: Path, out: Path, cprofile: Path | None,
                one_thread: bool = False) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env.pop("JTHERMO_NO_CACHE", None)
    env["JTHERMO_CACHE_DIR"] = str(cache)
    cmd = [sys.executable, __file__, "--child", str(est), str(val), str(out)]
    if cprofile is not None:
        cmd += ["--child-cprofile", str(cprofile)]
    if one_thread:
        cmd += ["--one-thread"]
    load0 = load1()
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env)
    row = json.loads(out.read_text())
    row.update(phase=phase, process_wall_s=time.perf_counter() - t0, load_before=load0, load_after=load1())
    print(phase, {k: row[k] for k in ("process_wall_s", "total_cpu_s", "compile_s", "compiles",
                                      "verdict", "augmented", "augmented_fit", "load_before")}, flush=True)
    return row


def _table(run: dict) -> list[str]:
    lines = [f"### {run['phase']}: {run['total_wall_s']:.1f} s wall in diagnose "
             f"({run['process_wall_s']:.1f} s process), {run['total_cpu_s']:.1f} CPU s, compile "
             f"{run['compile_s']:.1f} s ({run['compiles']} backend compiles, {run['cache_loads']} "
             f"cache loads), load {run['load_before']:.2f} → {run['load_after']:.2f}", "",
             "compile seconds by JAX event: " + ", ".join(
                 f"{k} {v:.2f}" for k, v in sorted(run.get("compile_by_event", {}).items())), "",
             "| stage: call | calls | wall s | CPU s | compile s | compiles |", "|---|---|---|---|---|---|"]
    for k, r in run["rows"].items():
        lines.append(f"| {k} | {r['calls']} | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | "
                     f"{r['compile_s']:.2f} | {r['compiles']} |")
    return lines


def write(runs: list[dict], cmdline: str, zones: int = 4) -> Path:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "diagnose_profile.json").write_text(json.dumps(runs, indent=1, default=float) + "\n")
    w = runs[-1]
    lines = ["# `jthermo diagnose` profile", "",
             f"`{cmdline}`: the latency record (1 h, {zones} zones; 30 min validation), diagnosed "
             "in-process, cold (empty compilation cache) then warm (second process). Stages are "
             "the diagnosis's progress ticks; `stage: call` rows are the compiled fits inside a "
             "stage (blocked until ready); stage rows include them. CPU s = user + system of the "
             "process (all threads), the load-robust figure; wall s is inflated by the load "
             "(2 shared cores).", "",
             f"Result ({w['phase']}): {w['verdict']}, findings {', '.join(w['findings'])}; augmented "
             f"{' + '.join(w['augmented'])}: mean validation fit {w['baseline_fit']:.2f} → "
             f"{w['augmented_fit']:.2f} % (zones {', '.join(f'{v:.2f}' for v in w['augmented_fit_per_zone'])}).", ""]
    for run in runs:
        lines += _table(run) + [""]
    out = RESULTS / "diagnose_profile.md"
    out.write_text("\n".join(lines))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cprofile", action="store_true", help="cProfile the cold run's diagnose()")
    ap.add_argument("--phases", default="cold,warm")
    ap.add_argument("--zones", type=int, default=4, help="the record's zones (the latency record: 4)")
    ap.add_argument("--one-thread", action="store_true",
                    help="JAX's CPU backend with one intra-op thread (runtime.one_thread_backend)")
    ap.add_argument("--child", nargs=3, metavar=("EST", "VAL", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--child-cprofile", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        est, val, out = args.child
        Path(out).write_text(json.dumps(run_once(est, val, args.child_cprofile, args.one_thread), default=float))
        return
    with tempfile.TemporaryDirectory(prefix="jthermo-diagprof-") as d:
        tmp = Path(d)
        write_record(tmp, args.zones)
        runs = []
        for phase in args.phases.split(","):
            cp = RESULTS / "diagnose_profile.cprofile.txt" if args.cprofile and phase == "cold" else None
            runs.append(_subprocess(phase, tmp / "est.csv", tmp / "val.csv", tmp / "cache",
                                    tmp / f"{phase}.json", cp, args.one_thread))
    cmd = "python benchmarks/diagnose_profile.py" + (f" --zones {args.zones}" if args.zones != 4 else "") + \
        (f" --phases {args.phases}" if args.phases != "cold,warm" else "") + \
        (" --cprofile" if args.cprofile else "") + (" --one-thread" if args.one_thread else "")
    print(write(runs, cmd, args.zones).read_text())


if __name__ == "__main__":
    main()
