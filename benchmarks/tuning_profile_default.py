"""Where `jthermo tune --controller C` (CLI defaults, virtual printer) spends its time, cold
(empty `JTHERMO_CACHE_DIR`) and warm (a second process on the cache the first one filled).

Each run is one fresh process that calls the CLI's own `main` with phase timers wrapped around
the functions `tune_report` calls (the same wrappers as `tuning_profile.py`): wall seconds,
compile seconds (JAX monitoring: trace + lower + backend compile) and backend compiles per
phase, exclusive of nested phases. The parent also records the child's wall and CPU seconds
(user + sys, `os.wait4`) and the 1-minute load when it started. With `--cprofile`, the warm
run's top functions by cumulative time are written next to the table.

    python benchmarks/tuning_profile_default.py --controller pi
    python benchmarks/tuning_profile_default.py --controller lqg --cli='--steps 60' --out OUT.md
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

ROOT = Path(__file__).resolve().parent.parent


def child(args) -> int:
    """Run the CLI in this process with phase timers; write the phase rows as JSON."""
    import cProfile
    import pstats

    sys.path.insert(0, str(ROOT / "benchmarks"))
    import tuning_profile as tp  # the phase wrappers and the compile-event listener

    from jthermo import cli
    from jthermo.tune import report, training

    for name in ("printer_model", "_printer_model"):     # the compiled one where it exists
        if hasattr(report, name):
            tp._wrap(report, name, "design model")
    tp._wrap(report, "tune", "tuning loop + guard (tune)")
    tp._wrap(training, "minimise", "tuning loop (minimise)")
    tp._wrap(training, "guarded_choice", "validation guard")
    tp._wrap(report, "classical_designs", "classical designs")
    tp._wrap(report, "held_out_terms", "held-out, changed powder, gain ±20 % (held_out_terms)")
    tp._wrap(report, "robustness", "robustness (Ms)")
    if hasattr(report, "_fixed_held_out"):
        tp._wrap(report, "_fixed_held_out", "fixed designs on held-out seeds (_fixed_held_out)")
    argv = ["tune", "--controller", args.controller, "--json", args.json, "--quiet",
            *args.cli.split()]
    prof = cProfile.Profile() if args.cprofile else None
    t0 = time.perf_counter()
    if prof is not None:
        prof.enable()
    rc = cli.main(argv)
    if prof is not None:
        prof.disable()
    total = time.perf_counter() - t0
    compile_s = sum(d for _, d, _ in tp._events)
    n_backend = sum(1 for e, _, _ in tp._events if "backend_compile" in e)
    out = {"rc": rc, "total": total, "compile_s": compile_s, "backend_compiles": n_backend,
           "rows": tp._rows}
    if prof is not None:
        path = Path(args.json).with_suffix(".cprofile.txt")
        with open(path, "w") as fh:
            pstats.Stats(prof, stream=fh).sort_stats("cumulative").print_stats(40)
        out["cprofile"] = str(path)
    Path(args.json).with_suffix(".phases.json").write_text(json.dumps(out))
    return rc


def run(controller: str, cache: str, js: str, cprofile: bool, cli: str = "") -> dict:
    env = {**os.environ, "JTHERMO_CACHE_DIR": cache, "JAX_ENABLE_X64": "1"}
    env.pop("JTHERMO_NO_CACHE", None)
    cmd = [sys.executable, __file__, "--child", "--controller", controller, "--json", js,
           f"--cli={cli}"]
    if cprofile:
        cmd.append("--cprofile")
    t = run_child(cmd, env)
    ph = json.loads(Path(js).with_suffix(".phases.json").read_text())
    rep = json.loads(Path(js).read_text())
    return {"wall": t["wall"], "cpu": t["cpu"], "load": t["load"], "phases": ph,
            "report": rep, "rss_mb": t["rss_mb"]}


def run_child(cmd: list, env: dict) -> dict:
    """Run `cmd` in the repository root with `env`: its wall s, CPU s (user + sys), peak RSS
    (MB) and the 1-min load when it started; a failed child stops the benchmark."""
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, cwd=ROOT)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"child failed: {' '.join(cmd)}")
    return {"wall": wall, "cpu": ru.ru_utime + ru.ru_stime, "load": load, "rss_mb": ru.ru_maxrss / 1024}


def table(controller: str, runs: dict, cli: str = "") -> str:
    opts = f" --cli='{cli}'" if cli else ""
    lines = [f"# `jthermo tune --controller {controller}{(' ' + cli) if cli else ''}` "
             f"({'CLI defaults otherwise' if cli else 'CLI defaults'}): time per phase",
             "",
             f"`python benchmarks/tuning_profile_default.py --controller {controller}{opts}`: "
             "one fresh "
             "process per run calling the CLI's `main`; cold = empty `JTHERMO_CACHE_DIR`, warm = "
             "a second process on the cache the first filled. Wall s, compile s (trace + lower + "
             "backend, JAX monitoring) and backend compiles per phase, exclusive of nested "
             "phases. Wall times are inflated by the load of the 2 shared cores (given per run); "
             "CPU s (user + sys of the process, all threads) is the load-robust figure.",
             ""]
    for name, r in runs.items():
        ph, rep = r["phases"], r["report"]
        lines += [f"## {name}: {r['wall']:.1f} s wall, {r['cpu']:.1f} CPU s, load "
                  f"{r['load']:.2f} at start, peak RSS {r['rss_mb']:.0f} MB",
                  "",
                  f"`--json`: seconds {rep.get('seconds', float('nan')):.1f} (compile_s "
                  f"{rep.get('compile_s', float('nan')):.1f} / run_s "
                  f"{rep.get('run_s', float('nan')):.1f}); held-out improvement vs lambda PI "
                  f"{rep['improvement_percent']:.2f} %, vs best classical "
                  f"{rep.get('improvement_vs_best_classical_percent', float('nan')):.2f} % "
                  f"({rep.get('best_classical')}); evaluations {rep.get('evaluations')}",
                  "",
                  "| phase | calls | wall s (exclusive) | compile s | backend compiles |",
                  "|---|---|---|---|---|"]
        accounted = 0.0
        for k, row in ph["rows"].items():
            second = row.get("second_thread", False)
            accounted += 0.0 if second else row["wall"]
            lines.append(f"| {k} | {row['calls']} | {row['wall']:.1f} | {row['compile']:.1f} | "
                         f"{row['compiles']} |")
        lines.append(f"| rest (imports, scenario building, CLI, report) | — | "
                     f"{ph['total'] - accounted:.1f} | — | — |")
        lines += ["", f"in-process total {ph['total']:.1f} s, compile {ph['compile_s']:.1f} s, "
                      f"{ph['backend_compiles']} backend compiles", ""]
        if "cprofile" in ph:
            lines += [f"cProfile (top functions by cumulative time): "
                      f"`{Path(ph['cprofile']).name}` in the results folder", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="pi")
    ap.add_argument("--out", default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--json", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--cprofile", action="store_true", help="cProfile the warm run")
    ap.add_argument("--cli", default="", help="further `jthermo tune` options, e.g. '--steps 60'")
    args = ap.parse_args(argv)
    if args.child:
        return child(args)
    out = Path(args.out or ROOT / "benchmarks" / "results"
               / "tuning_profile_default.md")
    with tempfile.TemporaryDirectory(prefix="jthermo-tune-prof-") as tmp:
        runs = {}
        for name in ("cold", "warm"):
            js = str(Path(tmp) / f"{name}.json")
            runs[name] = run(args.controller, str(Path(tmp) / "cache"), js,
                             args.cprofile and name == "warm", args.cli)
            print(name, f"{runs[name]['wall']:.1f} s wall", f"{runs[name]['cpu']:.1f} CPU s",
                  flush=True)
            cp = runs[name]["phases"].get("cprofile")
            if cp:
                target = out.with_suffix(".cprofile.txt")
                text = Path(cp).read_text().replace(str(ROOT) + "/", "")
                target.write_text(text)
                runs[name]["phases"]["cprofile"] = str(target)
        text = table(args.controller, runs, args.cli)
    out.write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
