"""Where `tune_report` (the library call behind `jthermo tune`) spends its time: wall time,
compile time and number of backend compiles per phase (the tuning loop, the validation guard,
the classical designs, the held-out and changed-powder comparisons, the robustness report).

Phases are timed by wrapping the module functions `tune_report` calls; compiles are counted
from JAX's monitoring events (`/jax/core/compile/backend_compile_duration`), so a phase that
re-compiles per candidate, scenario or design shows a count that grows with them. No
persistent compilation cache is enabled: every compile is paid (the cold case).

    python benchmarks/tuning_profile.py --rollouts 4 --steps 5          # reduced
    python benchmarks/tuning_profile.py --out benchmarks/results/tuning_profile.md   # defaults
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from jax import monitoring

from jthermo.tune import report, training

#: compile events `(event, seconds, thread id)`: a phase counts those of its own thread
#: (`tune_report` runs the fixed designs' held-out simulations in a second thread)
_events: list[tuple[str, float, int]] = []
monitoring.register_event_duration_secs_listener(
    lambda ev, dur, **_: _events.append((ev, dur, threading.get_ident()))
    if ev.startswith("/jax/core/compile") else None)

_local = threading.local()
_rows: dict[str, dict] = {}


def _thread_stack() -> list[str]:
    """This thread's stack of open phases."""
    if not hasattr(_local, "stack"):
        _local.stack = []
    return _local.stack


def _wrap(mod, name, label):
    """Replace `mod.name` by a timer that books wall time and compiles to `label` (a phase's
    figures exclude those of the phases nested in it)."""
    fn = getattr(mod, name)

    def timed(*a, **k):
        _stack = _thread_stack()
        second = threading.current_thread() is not threading.main_thread()
        lab_here = f"{label} — second thread, overlaps the others" if second else label
        _stack.append(lab_here)
        n0, t0 = len(_events), time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            dt = time.perf_counter() - t0
            _stack.pop()
            me = threading.get_ident()
            ev = [(e, d) for e, d, t in _events[n0:] if t == me]
            c = sum(d for e, d in ev if e.startswith("/jax/core/compile"))
            nc = sum(1 for e, _ in ev if "backend_compile" in e)
            for lab, sign in ((lab_here, 1.0), *((p, -1.0) for p in _stack)):
                # a parent phase's figures are exclusive of its nested phases
                row = _rows.setdefault(lab, {"calls": 0, "wall": 0.0, "compile": 0.0,
                                             "compiles": 0, "second_thread": second})
                row["calls"] += sign > 0
                row["wall"] += sign * dt
                row["compile"] += sign * c
                row["compiles"] += int(sign) * nc
    setattr(mod, name, timed)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--controller", default="pi_lambda")
    ap.add_argument("--rollouts", type=int, default=16)
    ap.add_argument("--steps", type=int, default=150)
    ap.add_argument("--optimiser", default=None, help="minimise's method (default: its default)")
    ap.add_argument("--out", default=None, help="write a Markdown table here")
    args = ap.parse_args(argv)

    _wrap(report, "tune", "tuning loop + guard (tune)")
    _wrap(training, "minimise", "tuning loop (minimise)")
    _wrap(training, "guarded_choice", "validation guard")
    _wrap(report, "classical_designs", "classical designs")
    _wrap(report, "printer_model", "design model")
    _wrap(report, "held_out_terms", "held-out, changed powder, gain ±20 % (held_out_terms)")
    _wrap(report, "robustness", "robustness (Ms)")
    kw = {} if args.optimiser is None else {"optimiser": args.optimiser}
    t0 = time.perf_counter()
    rep = report.tune_report(args.controller, rollouts=args.rollouts, steps=args.steps, **kw)
    total = time.perf_counter() - t0
    all_compile = sum(d for _, d, _ in _events)
    load = os.getloadavg()[0]
    lines = [(f"# tune_report profile: {args.controller}, rollouts {args.rollouts}, "
              f"steps {args.steps}{'' if args.optimiser is None else ', ' + args.optimiser}"),
             "",
             (f"`python benchmarks/tuning_profile.py --controller {args.controller} --rollouts "
              f"{args.rollouts} --steps {args.steps}"
              f"{'' if args.optimiser is None else ' --optimiser ' + args.optimiser}` "
              f"(no persistent cache; load average {load:.2f} on {os.cpu_count()} cores at the "
              "end: wall times are inflated by load)"),
             "",
             "| phase | calls | wall s (exclusive) | compile s | backend compiles |",
             "|---|---|---|---|---|"]
    for k, r in _rows.items():
        lines.append(f"| {k} | {r['calls']} | {r['wall']:.1f} | {r['compile']:.1f} | "
                     f"{r['compiles']} |")
    lines += ["", (f"total {total:.1f} s, compile (trace + lower + backend, all phases) "
                   f"{all_compile:.1f} s, {sum(1 for e, _, _ in _events if 'backend_compile' in e)} "
                   f"backend compiles; held-out improvement vs lambda PI "
                   f"{rep['improvement_percent']:.1f} %, vs best classical "
                   f"{rep.get('improvement_vs_best_classical_percent', float('nan')):.1f} %, "
                   f"gradient evaluations {rep['evaluations']}")]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
