"""Where a `jthermo simulate` process spends its wall and CPU seconds, cold and warm, as the
command itself runs (`cli.main`, then `cli.common.exit_now`): a timeline of stages, with every
JAX compile event (trace, lowering, backend compile or cache load) named by the jthermo line
that caused it.

A child process runs the command with a fresh empty `JTHERMO_CACHE_DIR` (cold), a second one
with the cache the first filled (warm). In each child the modules the command imports are
imported first, one group at a time (the same modules the command would import lazily), then
the command runs with its steps wrapped for time stamps (`make_printer`, the design model,
`design`, `closedloop.run`); JAX's compile events (`jax.monitoring`) are listed with their
cause. "eager programs" counts the compiled programs outside the run program (each traced,
lowered and looked up in the compilation cache on every call of the command).

    python benchmarks/simulate_timeline.py                  # -> results/simulate_timeline.md
    python benchmarks/simulate_timeline.py --out -          # print only
    git archive REV | (mkdir -p BASE && tar -x -C BASE)
    python benchmarks/simulate_timeline.py --tree BASE --label REV --out results/...md

CPU seconds are the child's user + system (all threads); the 1-minute load is noted: on the
shared 2-core machine wall seconds scale with it.
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

HERE = Path(__file__).resolve().parent
ARGV = ["simulate", "--scenario", "tracking", "--controller", "pi", "--zones", "16",
        "--rollouts", "256", "--duration", "3600", "--quiet"]

#: imported first in the child, group by group (what the command imports on its path)
IMPORTS = (("import jax", ("jax", "jax.numpy")),
           ("import equinox", ("equinox",)),
           ("import jthermo.cli, runtime, io", ("jthermo.cli", "jthermo.runtime", "jthermo.io")),
           ("import closedloop, control.design, printer",
            ("jthermo.closedloop", "jthermo.control.design", "jthermo.printer", "jthermo.stored")))

CHILD = r'''
import json, os, sys, time, traceback
t_up, c_up = time.time(), time.process_time()
rows, events = [], []
last = [t_up, c_up]
def stamp(name):
    t, c = time.time(), time.process_time()
    rows.append({"stage": name, "wall_s": t - last[0], "cpu_s": c - last[1], "at": t})
    last[0], last[1] = t, c
import importlib
for name, mods in IMPORTS:
    for m in mods:
        importlib.import_module(m)
    stamp(name)
import jax.monitoring
def on_event(event, duration, **_):
    if not event.startswith("/jax/core/compile/"):
        return
    where = [f for f in traceback.extract_stack() if "/jthermo/" in f.filename]
    site = (f"{where[-1].filename.split('/jthermo/')[-1]}:{where[-1].lineno}" if where else "?")
    events.append({"event": event.rsplit("/", 1)[-1], "s": duration, "site": site,
                   "at": time.time()})
jax.monitoring.register_event_duration_secs_listener(on_event)

import jthermo.cli.control as cc, jthermo.printer as jp, jthermo.closedloop as jcl
jd = sys.modules["jthermo.control.design"]
def wrap(mod, attr, name):
    fn = getattr(mod, attr)
    def inner(*a, **k):
        stamp("(command: argument parsing, set-up)" if name == "make_printer" else "(between)")
        out = fn(*a, **k)
        stamp(name)
        return out
    setattr(mod, attr, inner)
wrap(jp, "make_printer", "make_printer")
wrap(cc, "stored_printer_model", "design model (cached arrays)")
wrap(jd, "design", "design pi_lambda")
wrap(jcl, "run", "closedloop.run (run program: load + execute)")
from jthermo.cli import main
code = main(ARGV)
stamp("report, end of main")
json.dump({"t_up": t_up, "rows": rows, "events": events, "code": code}, open(OUT, "w"))
from jthermo.cli.common import exit_now
exit_now(code)
'''


def _load() -> str:
    return Path("/proc/loadavg").read_text().split()[0]


def _child(cache: str, tree: str | None) -> dict:
    """One command process: its stage rows, compile events, wall and CPU seconds."""
    with tempfile.NamedTemporaryFile(suffix=".json", delete=False) as f:
        out = f.name
    src = f"IMPORTS = {IMPORTS!r}\nARGV = {ARGV!r}\nOUT = {out!r}\n" + CHILD
    env = {**os.environ, "JTHERMO_CACHE_DIR": cache}
    if tree is not None:   # that source tree's jthermo ahead of the installed one
        env["PYTHONPATH"] = os.pathsep.join([tree, env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    load = _load()
    ru0 = os.times()
    t0 = time.time()
    subprocess.run([sys.executable, "-c", src], check=True, env=env, cwd=tree)
    wall = time.time() - t0
    ru1 = os.times()
    rep = json.loads(Path(out).read_text())
    os.unlink(out)
    rep.update(wall_s=wall, cpu_s=(ru1.children_user - ru0.children_user)
               + (ru1.children_system - ru0.children_system), load=load,
               startup_s=rep["t_up"] - t0)
    return rep


def _stage_table(cold: dict, warm: dict) -> list[str]:
    out = ["| stage | cold wall s | cold CPU s | warm wall s | warm CPU s |", "|---|---|---|---|---|",
           f"| interpreter start (to the first line) | {cold['startup_s']:.2f} |  | "
           f"{warm['startup_s']:.2f} |  |"]
    for a, b in zip(cold["rows"], warm["rows"]):
        out.append(f"| {a['stage']} | {a['wall_s']:.2f} | {a['cpu_s']:.2f} | {b['wall_s']:.2f} | "
                   f"{b['cpu_s']:.2f} |")
    for ph in (cold, warm):
        ph["sum_rows"] = sum(r["wall_s"] for r in ph["rows"])
    out.append(f"| whole process (from the shell) | {cold['wall_s']:.2f} | {cold['cpu_s']:.2f} | "
               f"{warm['wall_s']:.2f} | {warm['cpu_s']:.2f} |")
    return out


def _event_table(rep: dict) -> list[str]:
    out = ["| at s | event | s | caused by |", "|---|---|---|---|"]
    for e in rep["events"]:
        out.append(f"| {e['at'] - rep['t_up']:.2f} | {e['event']} | {e['s']:.3f} | `{e['site']}` |")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_timeline.md"))
    ap.add_argument("--tree", default=None, help="another source tree (default: this one)")
    ap.add_argument("--label", default="this checkout", help="how the title names the tree")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="jthermo-timeline-") as cache:
        cold = _child(cache, args.tree)
        warm = _child(cache, args.tree)
    n_prog = {k: len({(e["site"]) for e in r["events"] if e["event"].startswith("backend")})
              for k, r in (("cold", cold), ("warm", warm))}
    lines = ["# `jthermo simulate` timeline, cold and warm: N = 16, B = 256, T = 3600 s "
             f"({args.label})", "",
             "`python benchmarks/simulate_timeline.py`: the command run in-process by `cli.main` "
             "in a fresh child (cold: empty cache; warm: the cache the cold child filled), stages "
             "stamped, JAX compile events named by their jthermo call site. 1-minute load "
             f"{cold['load']} before the cold child, {warm['load']} before the warm one "
             "(2 shared cores: wall s scale with the load, CPU s less). Tree: "
             f"{'this checkout' if args.tree is None else '`--tree` ' + args.label}.", "",
             *_stage_table(cold, warm), "",
             f"Compiled programs (backend compiles or cache loads): cold {n_prog['cold']}, "
             f"warm {n_prog['warm']}.", "", "## Compile events, warm", "", *_event_table(warm),
             "", "## Compile events, cold", "", *_event_table(cold)]
    text = "\n".join(lines) + "\n"
    if args.out == "-":
        print(text)
    else:
        Path(args.out).write_text(text)
        print(text)


if __name__ == "__main__":
    main()
