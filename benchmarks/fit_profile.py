"""Where the cold `jthermo fit EST.csv --model M --validation VAL.csv --json OUT` spends its time
: the command run from the shell in a fresh process with an empty compilation cache,
on the W1 records of `benchmarks/identification.py --default-path` (absolute °C, 6000 + 3000
samples), its stages timed by wrapping the functions the command calls.

Stages (exclusive: a stage's time excludes the stages nested in it): interpreter start and the
command's imports (`startup`: until `cmd_fit` runs), `import library` (the lazy import of
`jthermo.identify.fit` and `jthermo.validate`), `read data`, `operating point`, `order
screening`, `ARX`, `PEM`, `guard`, `fit (rest)`, `validation` (`validate.compare`), `write
report`, and the rest (`other`). Each has its wall and CPU seconds (user + system of the
process, all threads) and the JAX compile events it caused (`jax.monitoring`: trace, lowering,
backend compile, count and seconds); the functions compiled are listed by name
(`jax_log_compiles`). Wall and peak RSS of the whole process come from /usr/bin/time.
`--imports` adds the cumulative import time of the heavy packages (`python -X importtime`).

    python benchmarks/fit_profile.py --n 4 --families arx armax oe bj --imports
    -> benchmarks/results/fit_profile.md (and .json)

The machine is shared: the 1-minute load is recorded with every row; CPU seconds are the
figure that depends least on the load.
"""

from __future__ import annotations

import time

T_START = time.perf_counter()
CPU_START = time.process_time()

import argparse  # noqa: E402
import collections  # noqa: E402
import json  # noqa: E402
import logging  # noqa: E402
import os  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "compile"}
#: (module, attribute, stage) wrapped in the child; the module is imported when first needed
STAGES = [
    ("jthermo.cli.identify", "require", "import library"),
    ("jthermo.cli.identify", "load_data", "read data"),
    ("jthermo.cli.identify", "write_report", "write report"),
    ("jthermo.identify.fit", "screen_orders", "order screening"),
    ("jthermo.identify.fit", "select_orders", "order screening"),
    ("jthermo.identify.polynomial", "estimate_rest_level", "operating point"),
    ("jthermo.identify.polynomial", "offset_mode", "operating point"),
    ("jthermo.identify.polynomial", "arx_ls", "ARX"),
    ("jthermo.identify.polynomial", "minimize_many", "PEM"),
    ("jthermo.identify.polynomial", "guard_polynomial", "guard"),
    ("jthermo.identify.fit", "fit", "fit (rest)"),
    ("jthermo.validate", "compare", "validation"),
]


def load() -> float:
    return os.getloadavg()[0]


# ----------------------------------------------------------------------------- child


class Profile:
    """Exclusive wall / CPU seconds and compile events per stage (a stack of open stages)."""

    def __init__(self):
        self.stack = ["cmd_fit (rest)"]
        self.wall = collections.Counter()
        self.cpu = collections.Counter()
        self.events = collections.defaultdict(collections.Counter)
        self.compiled = collections.defaultdict(collections.Counter)
        self.mark = (time.perf_counter(), time.process_time())

    def _charge(self):
        t, c = time.perf_counter(), time.process_time()
        self.wall[self.stack[-1]] += t - self.mark[0]
        self.cpu[self.stack[-1]] += c - self.mark[1]
        self.mark = (t, c)

    def wrap(self, fn, name):
        def wrapped(*a, **k):
            self._charge()
            self.stack.append(name)
            try:
                out = fn(*a, **k)
                if name != "import library":
                    import jax

                    try:
                        jax.block_until_ready(out)
                    except Exception:  # noqa: BLE001 (a result that is no pytree of arrays)
                        pass
                return out
            finally:
                self._charge()
                self.stack.pop()

        return wrapped

    def on_span(self, event, start, end, **_):
        if event in EVENTS:
            kind = EVENTS[event]
            self.events[self.stack[-1]][kind] += 1
            self.events[self.stack[-1]][kind + "_s"] += end - start


class _CompileLog(logging.Handler):
    """Names of the functions JAX compiles (`jax_log_compiles` messages)."""

    def __init__(self, prof: Profile):
        super().__init__(logging.DEBUG)
        self.prof = prof

    def emit(self, record):
        m = re.match(r"Compiling (\S+)", record.getMessage())
        if m:
            self.prof.compiled[self.prof.stack[-1]][m.group(1)] += 1


def child(argv: list[str], out: Path) -> int:
    import importlib

    import jthermo.cli as cli

    prof = Profile()
    prof.wall["startup"] = time.perf_counter() - T_START
    prof.cpu["startup"] = time.process_time() - CPU_START
    import jthermo.cli.identify as ident

    cmd = ident.cmd_fit

    def cmd_fit(args):
        # the library modules are wrapped once `require` has imported them
        import jax
        import jax.monitoring

        jax.config.update("jax_log_compiles", True)
        for lg in ("jax._src.interpreters.pxla", "jax._src.dispatch", "jax"):
            logging.getLogger(lg).addHandler(_CompileLog(prof))
            logging.getLogger(lg).propagate = False
        jax.monitoring.register_event_time_span_listener(prof.on_span)
        prof.stack[-1] = "import jax"     # cli.main's imports and settings until here
        prof._charge()
        prof.stack[-1] = "cmd_fit (rest)"
        for mod, attr, name in STAGES[:3]:
            m = importlib.import_module(mod)
            setattr(m, attr, prof.wrap(getattr(m, attr), name))
        require = ident.require

        def require_and_wrap(name, what):
            m = require(name, what)
            for mod, attr, stage in STAGES[3:]:
                mm = sys.modules.get(mod)
                if mm is not None and hasattr(mm, attr) and not hasattr(getattr(mm, attr), "_p"):
                    w = prof.wrap(getattr(mm, attr), stage)
                    w._p = True
                    setattr(mm, attr, w)
            return m

        ident.require = require_and_wrap
        return cmd(args)

    cli.COMMANDS["fit"] = cmd_fit
    rc = cli.main(argv)
    prof._charge()
    out.write_text(json.dumps({"rc": rc, "wall": prof.wall, "cpu": prof.cpu,
                               "events": prof.events, "compiled": prof.compiled,
                               "total_wall": time.perf_counter() - T_START,
                               "total_cpu": time.process_time() - CPU_START}, indent=1))
    return rc


# ----------------------------------------------------------------------------- parent


def import_times() -> list[tuple[str, float]]:
    """Cumulative import seconds of the heavy packages of the fit command's imports."""
    code = "import jthermo.cli, jthermo.identify.fit, jthermo.validate, jthermo.io"
    p = subprocess.run([sys.executable, "-X", "importtime", "-c", code], capture_output=True,
                       text=True, cwd=ROOT)
    rows = []
    for line in p.stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|(\s*)(\S+)", line)
        if m and len(m.group(3)) <= 2:       # top-level imports only
            rows.append((m.group(4), int(m.group(2)) / 1e6))
    return sorted(rows, key=lambda r: -r[1])[:14]


def run(N: int, families: list[str], seed: int = 0) -> list[dict]:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import identification as B

    W = B.load_workloads()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        B.write_default_records(W, N, seed, tmp)
        for fam in families:
            print(f"[fit profile] N={N} {fam} ...", file=sys.stderr, flush=True)
            prof, tm = tmp / f"{fam}.prof.json", tmp / f"{fam}.time"
            env = {**os.environ, "JTHERMO_CACHE_DIR": str(tmp / f"cache_{fam}")}
            l0 = load()
            cmd = ["/usr/bin/time", "-f", "%e %U %S %M", "-o", str(tm), sys.executable,
                   str(Path(__file__).resolve()), "--child", str(prof), "--", "fit",
                   str(tmp / "est.csv"), "--model", fam, "--validation", str(tmp / "val.csv"),
                   "--json", str(tmp / f"{fam}.json"), "--quiet"]
            p = subprocess.run(cmd, env=env, capture_output=True, text=True)
            wall, user, sys_s, rss = (float(v) for v in tm.read_text().split()[-4:])
            row = {"family": fam, "N": N, "rc": p.returncode, "wall_s": wall, "cpu_s": user + sys_s,
                   "peak_rss_mb": rss / 1024, "load": [l0, load()]}
            if p.returncode == 0:
                row["profile"] = json.loads(prof.read_text())
                rep = json.loads((tmp / f"{fam}.json").read_text())
                row["report"] = {k: rep.get(k) for k in ("orders", "mean_fit_percent",
                                                          "fit_percent", "converged", "seconds")}
            else:
                row["error"] = p.stderr[-400:]
            rows.append(row)
    return rows


ORDER = ["startup", "import jax", "import library", "read data", "operating point",
         "order screening", "ARX", "PEM", "guard", "fit (rest)", "validation", "write report",
         "cmd_fit (rest)"]


def markdown(rows: list[dict], imports: list, command: str) -> str:
    lines = ["# Cold `jthermo fit` profile", "",
             f"`{command}`: `jthermo fit EST.csv --model M --validation VAL.csv --json OUT` on W1 "
             "records (absolute °C, 6000 + 3000 samples), fresh process, empty compilation cache. "
             "Stage seconds are exclusive (nested stages subtracted); CPU = user + system of the "
             "process; compiles = backend compiles (their seconds, and trace + lowering seconds); "
             "load = 1-minute load average before / after (2 shared cores: wall times are "
             "inflated by the load, CPU seconds much less).", ""]
    for r in rows:
        head = (f"## {r['family']}, N = {r['N']}: {r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU, "
                f"peak RSS {r['peak_rss_mb']:.0f} MB, load {r['load'][0]:.1f} / {r['load'][1]:.1f}")
        lines += [head, ""]
        if r["rc"] != 0:
            lines += [f"exit {r['rc']}: {r.get('error', '')}", ""]
            continue
        p, rep = r["profile"], r["report"]
        lines += [f"orders {rep['orders']}, validation fit {rep['mean_fit_percent']:.2f} %, "
                  f"converged {rep['converged']}", "",
                  "| stage | wall s | CPU s | compiles | compile s | trace + lower s | functions compiled |",
                  "|---|---|---|---|---|---|---|"]
        stages = ORDER + sorted(set(p["wall"]) - set(ORDER))
        for s in stages:
            if s not in p["wall"]:
                continue
            ev = p["events"].get(s, {})
            names = ", ".join(f"{k} ×{v}" if v > 1 else k
                              for k, v in sorted(p["compiled"].get(s, {}).items(), key=lambda kv: -kv[1]))
            lines.append(f"| {s} | {p['wall'][s]:.2f} | {p['cpu'][s]:.2f} | {ev.get('compile', 0)} | "
                         f"{ev.get('compile_s', 0.0):.2f} | {ev.get('trace_s', 0.0) + ev.get('lower_s', 0.0):.2f} | "
                         f"{names} |")
        n_c = sum(e.get("compile", 0) for e in p["events"].values())
        s_c = sum(e.get("compile_s", 0.0) + e.get("trace_s", 0.0) + e.get("lower_s", 0.0)
                  for e in p["events"].values())
        lines += [f"| **total** (in process) | {p['total_wall']:.2f} | {p['total_cpu']:.2f} | {n_c} | "
                  f"| {s_c:.2f} (all compile events) | |", ""]
    if imports:
        lines += ["## Imports of the fit command (`python -X importtime`, cumulative, top level)", "",
                  "| module | s |", "|---|---|"] + [f"| {m} | {s:.2f} |" for m, s in imports] + [""]
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        return child(argv[3:], Path(argv[1]))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=4)
    ap.add_argument("--families", nargs="+", default=["arx", "armax", "oe", "bj"])
    ap.add_argument("--imports", action="store_true", help="add the import-time table")
    ap.add_argument("--out", type=Path, default=None,
                    help="Markdown path (default benchmarks/results/fit_profile.md)")
    args = ap.parse_args(argv)
    out = args.out or RESULTS / "fit_profile.md"
    rows = run(args.n, args.families)
    imports = import_times() if args.imports else []
    command = "python benchmarks/fit_profile.py " + " ".join(argv)
    from jthermo.data import atomic_write_text

    atomic_write_text(out, markdown(rows, imports, command))
    atomic_write_text(out.with_suffix(".json"), json.dumps({"command": command, "rows": rows,
                                                             "imports": imports}, indent=1))
    print(markdown(rows, imports, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
