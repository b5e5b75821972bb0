"""Where the fixed-order W1 fit of `benchmarks/identification.py` spends its first call, with an
empty persistent compilation cache (cold) and with the cache the cold process wrote (cached):
the columns on which jthermo is compared with SIPPY.

Each (family, N) runs in two fresh processes sharing one new cache directory, exactly as
`identification.run_jthermo` does; each times the first `identification.jthermo_fit` call (the
same options), its stages wrapped as in `benchmarks/fit_profile.py` (`fit_profile.STAGES`:
operating point, ARX, PEM, guard, the rest of `fit`), with wall and CPU seconds (user + system of
the process, all threads) and JAX's compile events per stage: trace, lowering, backend compile
(count and seconds) and persistent-cache reads (`cache s`). Trace and lowering run in every new
process, the cache only saves the backend compile: what is left in the cached column is the
floor a second process pays before it runs.

    python benchmarks/peers_fixed_profile.py --n 4 --families armax oe bj
    -> benchmarks/results/peers_fixed_profile.md (and .json)

The machine is shared: the 1-minute load is recorded; CPU seconds depend least on it.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import fit_profile
import identification as B

#: stages of the in-process fit (the CLI's stages of `fit_profile.STAGES` are not called here)
STAGES = [s for s in fit_profile.STAGES if not s[0].startswith("jthermo.cli")]
ORDER = ["operating point", "ARX", "PEM", "guard", "fit (rest)"]


def child(family: str, N: int, cache: str, out: Path) -> None:
    """Fresh process: cache at `cache`, the first fixed-order fit call, profiled by stage."""
    import importlib

    import jax
    import jax.monitoring

    jax.config.update("jax_enable_x64", True)
    from jthermo import runtime
    from jthermo.data import from_arrays

    runtime.enable_cache(cache)
    W = B.load_workloads()
    est, _ = W.estimation_validation(N, B.T, 0)
    data = from_arrays(est["u"], est["y"])
    prof = fit_profile.Profile()
    prof.stack[-1] = "outside"
    for mod, attr, stage in STAGES:
        m = importlib.import_module(mod)
        setattr(m, attr, prof.wrap(getattr(m, attr), stage))
    fit_call = prof.wrap(B.jthermo_fit, "fit (rest)")
    jax.config.update("jax_log_compiles", True)
    for lg in ("jax._src.interpreters.pxla", "jax._src.dispatch", "jax"):
        logging.getLogger(lg).addHandler(fit_profile._CompileLog(prof))  # same script family
        logging.getLogger(lg).propagate = False
    jax.monitoring.register_event_time_span_listener(prof.on_span)

    def on_duration(event, secs, **_):
        if "compilation_cache" in event and "retrieval" in event:
            prof.events[prof.stack[-1]]["cache_s"] += secs

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    t0, c0 = time.perf_counter(), time.process_time()
    res = fit_call(family, data, N)
    jax.block_until_ready(res.model)
    out.write_text(json.dumps({"wall": prof.wall, "cpu": prof.cpu, "events": prof.events,
                               "compiled": prof.compiled, "call_s": time.perf_counter() - t0,
                               "call_cpu": time.process_time() - c0,
                               "load": os.getloadavg()[0]}, indent=1))


def run(N: int, families: list[str]) -> list[dict]:
    rows = []
    for fam in families:
        with tempfile.TemporaryDirectory(prefix="jthermo-prof-cache-") as tmp:
            row = {"family": fam, "N": N}
            for which in ("cold", "cached"):
                print(f"[fixed profile] N={N} {fam} {which} ...", file=sys.stderr, flush=True)
                out = Path(tmp) / f"{which}.json"
                cmd = ["nice", "-n", "5", sys.executable, str(Path(__file__).resolve()),
                       "--child", fam, str(N), str(Path(tmp) / "cache"), str(out)]
                p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=False)
                if p.returncode != 0:
                    row[which] = {"error": (p.stderr.strip().splitlines() or ["?"])[-1][:200]}
                    break
                row[which] = json.loads(out.read_text())
        rows.append(row)
    return rows


def markdown(rows: list[dict], command: str) -> str:
    lines = ["# Fixed-order W1 fit: cold and cached first call, by stage", "",
             (f"`{command}`; options of `benchmarks/identification.py` (fixed orders, rest level "
             "0, 4 starts). Cold = fresh process, empty persistent compilation cache; cached = a "
             "second fresh process reading the cache the first wrote. Stage seconds are exclusive "
             "(nested stages subtracted); CPU = user + system of the process, all threads; "
             "compiles = backend compiles (count, seconds); trace + lower = JAX tracing and "
             "lowering seconds (paid in every process); cache s = persistent-cache reads. Load = "
             "1-minute load average (2 shared cores: wall times inflated, CPU seconds much less)."),
             ""]
    f = (lambda v: f"{v:.2f}")
    for r in rows:
        c, k = r.get("cold", {}), r.get("cached", {})
        if "error" in c or "error" in k:
            lines += [f"## {r['family']}, N = {r['N']}: {c.get('error') or k.get('error')}", ""]
            continue
        lines += [(f"## {r['family']}, N = {r['N']}: first call {f(c['call_s'])} s wall / "
                  f"{f(c['call_cpu'])} s CPU cold, {f(k['call_s'])} / {f(k['call_cpu'])} cached "
                  f"(load {c['load']:.1f} / {k['load']:.1f})"), "",
                  ("| stage | cold CPU s | compiles | compile s | trace + lower s | cached CPU s "
                  "| compiles | trace + lower s | cache s | functions compiled (cold) |"),
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for st in ORDER:
            if st not in c["cpu"] and st not in k["cpu"]:
                continue
            e, ek = c["events"].get(st, {}), k["events"].get(st, {})
            names = ", ".join(f"{n} ×{m}" if m > 1 else n
                              for n, m in sorted(c["compiled"].get(st, {}).items()))
            lines.append(
                f"| {st} | {f(c['cpu'].get(st, 0))} | {e.get('compile', 0)} | "
                f"{f(e.get('compile_s', 0))} | {f(e.get('trace_s', 0) + e.get('lower_s', 0))} | "
                f"{f(k['cpu'].get(st, 0))} | {ek.get('compile', 0)} | "
                f"{f(ek.get('trace_s', 0) + ek.get('lower_s', 0))} | {f(ek.get('cache_s', 0))} | "
                f"{names} |")
        lines.append("")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=4)
    ap.add_argument("--families", nargs="+", default=["armax", "oe", "bj"],
                    choices=[f for f in B.FAMILIES if f != "n4sid"])
    ap.add_argument("--out", type=Path, default=None,
                    help="default benchmarks/results/peers_fixed_profile.md")
    args = ap.parse_args(argv)
    if args.child:
        fam, n, cache, out = args.child
        child(fam, int(n), cache, Path(out))
        return 0
    out = args.out or B.RESULTS / "peers_fixed_profile.md"
    command = "python benchmarks/peers_fixed_profile.py " + " ".join(argv or sys.argv[1:])
    rows = run(args.n, args.families)
    out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    out.write_text(markdown(rows, command))
    print(markdown(rows, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
