"""Which programs `jthermo tune --controller C` (CLI defaults) compiles, cold and warm: one row
per compiled program (JAX's `jax_log_compiles` records: trace, lowering and backend compile
seconds, the argument shapes, the thread), grouped by function name so that near duplicates
(the same function at other shapes, dtypes or static arguments) show as several rows of one
name.

Each run is a fresh process calling the CLI's `main`; cold = an empty `JTHERMO_CACHE_DIR`, warm =
a second process on the cache the first filled. The parent records wall and CPU seconds (user +
sys, `os.wait4`) and the 1-minute load at the start.

    python benchmarks/tune_compiles.py --controller pi --tag s31_base
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import importlib
import json
import logging
import os
import re
import sys
import tempfile
import threading
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"

_TRACE = re.compile(r"Finished tracing \+ transforming (\S+) .*in ([0-9.e-]+) sec|"
                    r"Finished tracing (\S+) for jit in ([0-9.e-]+) sec")
_LOWER = re.compile(r"Finished jaxpr to MLIR module conversion (\S+) in ([0-9.e-]+) sec")
_SHAPES = re.compile(r"Compiling (\S+) with global shapes and types (.*?)\. Argument mapping",
                     re.S)
_XLA = re.compile(r"Finished XLA compilation of (\S+) in ([0-9.e-]+) sec")
_HIT = re.compile(r"Persistent compilation cache hit for '([^']+)'")


def child(args) -> int:
    """Run the CLI in this process with every compile logged; write the records as JSON."""
    import jax

    jax.config.update("jax_log_compiles", True)
    recs: list[dict] = []
    t_start = time.perf_counter()

    class H(logging.Handler):
        def emit(self, r):
            msg = r.getMessage()
            where = ""
            if msg.startswith("Compiling "):
                # the innermost jthermo frame that asked for this program
                fr = [f for f in traceback.extract_stack()
                      if "/jthermo/" in f.filename and "site-packages" not in f.filename]
                where = (f"{Path(fr[-1].filename).parent.name}/{Path(fr[-1].filename).name}:"
                         f"{fr[-1].lineno} {fr[-1].name}") if fr else ""
            recs.append({"t": time.perf_counter() - t_start,
                         "thread": threading.current_thread().name, "msg": msg,
                         "where": where})

    lg = logging.getLogger("jax")
    lg.addHandler(H())
    lg.setLevel(logging.WARNING)
    lg.propagate = False
    from jthermo import cli
    from jthermo.tune import report, training

    for spec in args.patch:        # MODULE.ATTR=JSON: a setting of the code under test
        target, value = spec.split("=", 1)
        mod, attr = target.rsplit(".", 1)
        setattr(importlib.import_module(mod), attr, json.loads(value))
    spans: list[dict] = []

    def timed(mod, name):
        fn = getattr(mod, name)

        def wrapper(*a, **k):
            t0 = time.perf_counter() - t_start
            try:
                return fn(*a, **k)
            finally:
                spans.append({"name": name, "thread": threading.current_thread().name,
                              "start": t0, "end": time.perf_counter() - t_start,
                              "thread_cpu": time.thread_time()})
        setattr(mod, name, wrapper)

    for mod, name in ((training, "minimise"), (training, "guarded_choice"), (report, "tune"),
                      (report, "_fixed_held_out"), (report, "_training_sets"),
                      (report, "_printer_model"), (report, "robustness")):
        timed(mod, name)
    argv = ["tune", "--controller", args.controller, "--json", args.json, "--quiet",
            *args.cli.split()]
    rc = cli.main(argv)
    main_cpu = time.thread_time()
    Path(args.json).with_suffix(".compiles.json").write_text(
        json.dumps({"rc": rc, "total": time.perf_counter() - t_start, "records": recs,
                    "spans": spans, "main_thread_cpu": main_cpu}))
    return rc


def programs(recs: list[dict]) -> list[dict]:
    """One row per backend compile (or persistent-cache hit), with the trace and lowering
    seconds of the same thread's last such records before it."""
    rows, last = [], {}
    for r in recs:
        th, m = r["thread"], r["msg"]
        st = last.setdefault(th, {"trace": 0.0, "lower": 0.0, "shapes": "", "where": ""})
        if (g := _TRACE.search(m)):
            st["trace"] += float(g.group(2) or g.group(4))
        elif (g := _LOWER.search(m)):
            st["lower"] += float(g.group(2))
        elif (g := _SHAPES.search(m)):
            st["shapes"], st["where"] = g.group(2), r.get("where", "")
        elif (g := _XLA.search(m)) or (h := _HIT.search(m)):
            name = g.group(1) if g else h.group(1)
            rows.append({"name": name, "thread": th, "t_end": r["t"],
                         "trace": st["trace"], "lower": st["lower"],
                         "backend": float(g.group(2)) if g else 0.0, "hit": g is None,
                         "shapes": st["shapes"], "where": st["where"],
                         "sig": hashlib.sha1(st["shapes"].encode()).hexdigest()[:6]})
            last[th] = {"trace": 0.0, "lower": 0.0, "shapes": "", "where": ""}
    return rows


def run(controller: str, cache: str, js: str, cli: str, patch=()) -> dict:
    env = {**os.environ, "JTHERMO_CACHE_DIR": cache}
    env.pop("JTHERMO_NO_CACHE", None)
    cmd = [sys.executable, __file__, "--child", "--controller", controller, "--json", js,
           f"--cli={cli}", *(f"--patch={p}" for p in patch)]
    from tuning_profile_default import run_child

    t = run_child(cmd, env)
    data = json.loads(Path(js).with_suffix(".compiles.json").read_text())
    rep = json.loads(Path(js).read_text())
    return {"wall": t["wall"], "cpu": t["cpu"], "load": t["load"],
            "rows": programs(data["records"]), "report": rep, "spans": data["spans"],
            "total": data["total"], "main_thread_cpu": data["main_thread_cpu"],
            "second_thread_cpu": max([x["thread_cpu"] for x in data["spans"]
                                      if x["thread"] != "MainThread"], default=0.0)}


def table(name: str, r: dict) -> list[str]:
    rep, rows = r["report"], r["rows"]
    back = sum(x["backend"] for x in rows)
    tr = sum(x["trace"] for x in rows)
    lo = sum(x["lower"] for x in rows)
    out = [f"## {name}: {r['wall']:.1f} s wall, {r['cpu']:.1f} CPU s, load {r['load']:.2f} at "
           "start", "",
           f"CPU s of the main thread {r['main_thread_cpu']:.1f} (its own work: on idle cores the "
           f"wall time's floor, waits for the second thread aside), of the second thread up to "
           f"its last phase {r['second_thread_cpu']:.1f}", "",
           f"`--json`: seconds {rep.get('seconds', float('nan')):.1f} (compile_s "
           f"{rep.get('compile_s', float('nan')):.1f} / run_s {rep.get('run_s', float('nan')):.1f}); "
           f"held-out improvement vs lambda PI {rep['improvement_percent']:.6f} %, vs best "
           f"classical {rep.get('improvement_vs_best_classical_percent', float('nan')):.6f} %, "
           f"evaluations {rep.get('evaluations')}, tuned cost {rep.get('tuned_cost')!r}", "",
           f"{len(rows)} programs ({sum(x['hit'] for x in rows)} from the persistent cache); "
           f"trace {tr:.1f} s, lowering {lo:.1f} s, backend compile {back:.1f} s (summed over "
           "threads)", "",
           "Phases (in-process s from the start of `main`): " + "; ".join(
               f"{x['name']} {x['start']:.1f}-{x['end']:.1f}"
               + ("" if x["thread"] == "MainThread" else " (2nd thread)")
               for x in r["spans"]) + f"; end {r['total']:.1f}", "",
           "| function | programs (distinct signatures) | cache hits | threads | trace s | "
           "lower s | backend s | largest backend s | asked for at (innermost jthermo frame) |",
           "|---|---|---|---|---|---|---|---|---|"]
    by = collections.defaultdict(list)
    for x in rows:
        by[x["name"]].append(x)
    for k, xs in sorted(by.items(), key=lambda kv: -sum(x["backend"] + x["trace"] + x["lower"]
                                                       for x in kv[1])):
        out.append(f"| `{k}` | {len(xs)} ({len({x['sig'] for x in xs})}) | "
                   f"{sum(x['hit'] for x in xs)} | "
                   f"{', '.join(sorted({x['thread'] for x in xs}))} | "
                   f"{sum(x['trace'] for x in xs):.2f} | {sum(x['lower'] for x in xs):.2f} | "
                   f"{sum(x['backend'] for x in xs):.2f} | {max(x['backend'] for x in xs):.2f} | "
                   f"{'; '.join(sorted({x.get('where', '') for x in xs}))[:200]} |")
    big = sorted(rows, key=lambda x: -(x["backend"] + x["lower"] + x["trace"]))[:12]
    out += ["", "Largest programs (trace + lower + backend s), their argument shapes (truncated):",
            "", "| function | thread | ends at s | trace | lower | backend | shapes |",
            "|---|---|---|---|---|---|---|"]
    for x in big:
        sh = x["shapes"].replace("|", "/").replace("\n", " ")
        sh = (sh[:300] + " …") if len(sh) > 300 else sh
        out.append(f"| `{x['name']}` | {x['thread']} | {x['t_end']:.1f} | {x['trace']:.2f} | "
                   f"{x['lower']:.2f} | {x['backend']:.2f} | {sh} |")
    return out + [""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="pi")
    ap.add_argument("--tag", default="")
    ap.add_argument("--cli", default="", help="further `jthermo tune` options")
    ap.add_argument("--cold-only", action="store_true")
    ap.add_argument("--patch", action="append", default=[],
                    help="MODULE.ATTR=JSON set in the child before it runs (repeatable)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--json", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        return child(args)
    tag = f"_{args.tag}" if args.tag else ""
    out = RESULTS / f"tune_compiles_{args.controller}{tag}.md"
    runs = {}
    with tempfile.TemporaryDirectory(prefix="jthermo-tune-comp-") as tmp:
        cache = os.path.join(tmp, "cache")
        for name in ("cold",) if args.cold_only else ("cold", "warm"):
            runs[name] = run(args.controller, cache, os.path.join(tmp, f"{name}.json"), args.cli,
                             args.patch)
    lines = [f"# Programs compiled by `jthermo tune --controller {args.controller}"
             f"{(' ' + args.cli) if args.cli else ''}`", "",
             f"`python benchmarks/tune_compiles.py --controller {args.controller}"
             f"{(' --tag ' + args.tag) if args.tag else ''}"
             f"{(' --cli=' + repr(args.cli)) if args.cli else ''}"
             f"{''.join(' --patch=' + repr(p) for p in args.patch)}`: one fresh process per run "
             "(cold: empty cache; warm: a second process on it), every compile logged "
             "(`jax_log_compiles`). Rows grouped by function name; several distinct signatures "
             "of one name are the same function compiled at other shapes, dtypes or static "
             "arguments.", ""]
    for name, r in runs.items():
        lines += table(name, r)
    out.write_text("\n".join(lines))
    (out.with_suffix(".json")).write_text(json.dumps(
        {k: {kk: vv for kk, vv in v.items()} for k, v in runs.items()}, default=str))
    print(out.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
