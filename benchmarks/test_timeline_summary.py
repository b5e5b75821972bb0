"""Per-file wall time and per-worker balance of a test run recorded by `test_timeline.py`.

    python benchmarks/test_timeline_summary.py out.jsonl [--top 40] [--cpu]
    python benchmarks/test_timeline_summary.py --headline cold=cold.jsonl warm=warm.jsonl
A file's time runs from its first test's start to its last test's end (module fixtures and
the compiled-code release between modules fall inside or between them); a worker's idle tail
is the time from its last test's end to the last test's end on any worker. Where the timeline
has JAX's program-making seconds (`test_timeline.py`), their sums, the backend compiles by
duration, the tests' time outside program making, and per file the seconds of tracing,
lowering and compiling (a persistent-cache read included)."""
import argparse
import itertools
import json
from collections import defaultdict


def load(path):
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def worker_rows(rows):
    """The workers' rows: the xdist controller (`main`) echoes its workers' tests."""
    if any(r["worker"] != "main" for r in rows):
        return [r for r in rows if r["worker"] != "main"]
    return rows


#: JAX's program-making phases of a timeline row (`test_timeline.EVENTS`)
PHASES = ("trace", "lower", "compile", "cache_read")


def jax_totals(rows) -> dict:
    """{phase: [seconds, events]} summed over the rows that have JAX's figures."""
    jx = [r["jax"] for r in rows if "jax" in r]
    return {k: [sum(j[k][0] for j in jx), sum(j[k][1] for j in jx)] for k in PHASES}


def summarise(rows, top, by_cpu=False):
    rows = worker_rows(rows)
    t0 = min(r["start"] for r in rows)
    t_end = max(r["end"] for r in rows)
    files = defaultdict(lambda: [float("inf"), 0.0, 0, None, 0.0])
    for r in rows:
        f = files[r["test"].split("::")[0]]
        f[0], f[1], f[2], f[3] = min(f[0], r["start"]), max(f[1], r["end"]), f[2] + 1, r["worker"]
        f[4] += r.get("cpu") or 0.0
    out = [f"span of the tests: {t_end - t0:.1f} s, {len(rows)} tests, {len(files)} files", ""]
    workers = defaultdict(lambda: [0.0, 0.0])
    for r in rows:
        w = workers[r["worker"]]
        w[0] += r["end"] - r["start"]
        w[1] = max(w[1], r["end"])
    out += ["| worker | busy s (sum of tests) | last test ends at s | idle tail s |", "|---|---|---|---|"]
    for name, (busy, last) in sorted(workers.items()):
        out.append(f"| {name} | {busy:.1f} | {last - t0:.1f} | {t_end - last:.1f} |")
    cpu = sum(f[4] for f in files.values())
    out += ["", f"CPU s of the tests (user + sys, subprocesses included): {cpu:.1f}", "",
            "| file | worker | tests | wall s | CPU s | starts at s | ends at s |",
            "|---|---|---|---|---|---|---|"]
    key = (lambda kv: -kv[1][4]) if by_cpu else (lambda kv: kv[1][0] - kv[1][1])
    for name, (s, e, n, w, c) in sorted(files.items(), key=key)[:top]:
        out.append(f"| {name} | {w} | {n} | {e - s:.1f} | {c:.1f} | {s - t0:.1f} | {e - t0:.1f} |")
    out += ["", *jax_phases(rows, files_order=[n for n, _ in sorted(files.items(), key=key)[:top]])]
    out += ["", "last files to start:"]
    for name, (s, e, n, w, _) in sorted(files.items(), key=lambda kv: kv[1][0])[-6:]:
        out.append(f"  {name} ({w}) {s - t0:.1f} -> {e - t0:.1f}")
    return "\n".join(out)


#: bounds (s) of the backend-compile duration classes
BINS = (0.05, 0.5, 5.0)


def jax_phases(rows, files_order) -> list[str]:
    """JAX's program making summed over the tests (empty where the timeline has none)."""
    rows = [r for r in rows if "jax" in r]
    if not rows:
        return []
    tot = jax_totals(rows)
    busy = sum(r["end"] - r["start"] for r in rows)
    making = tot["trace"][0] + tot["lower"][0] + tot["compile"][0]
    out = ["JAX's program making in the workers (a subprocess's not seen):", "",
           "| phase | s | events |", "|---|---|---|"]
    out += [f"| {k} | {tot[k][0]:.1f} | {tot[k][1]} |" for k in PHASES]
    out += ["", (f"busy s of the tests: {busy:.1f}; of it tracing + lowering + backend compile "
                 f"(cache reads included): {making:.1f}; the rest (running, Python, subprocesses): "
                 f"{busy - making:.1f}"), "", "| backend compile of one program | programs | s |",
            "|---|---|---|"]
    durations = [d for r in rows for d in r.get("compiles", [])]
    edges = (0.0, *BINS, float("inf"))
    for lo, hi in itertools.pairwise(edges):
        ds = [d for d in durations if lo <= d < hi]
        out.append(f"| {lo:g} to {hi:g} s | {len(ds)} | {sum(ds):.1f} |")
    per = defaultdict(lambda: [0.0, 0.0, 0.0, 0])
    for r in rows:
        f = per[r["test"].split("::")[0]]
        for i, k in enumerate(("trace", "lower", "compile")):
            f[i] += r["jax"][k][0]
        f[3] += r["jax"]["compile"][1]
    out += ["", "| file | trace s | lower s | compile s | programs |", "|---|---|---|---|---|"]
    out += [f"| {n} | {per[n][0]:.1f} | {per[n][1]:.1f} | {per[n][2]:.1f} | {per[n][3]} |"
            for n in files_order if n in per]
    return out


#: the header of `headline_row`'s table
HEADLINE = ("| run | wall of the tests s | busy s (both workers) | programs made | of them read from "
            "the cache | tracing + lowering s | backend compile s (reads included) | the rest s |\n"
            "|---|---|---|---|---|---|---|---|")


def headline_row(rows, label: str) -> str:
    """One row of `HEADLINE`: the run's span, its busy seconds and JAX's program making."""
    rows = worker_rows(rows)
    span = max(r["end"] for r in rows) - min(r["start"] for r in rows)
    busy = sum(r["end"] - r["start"] for r in rows)
    tot = jax_totals(rows)
    tl = tot["trace"][0] + tot["lower"][0]
    return (f"| {label} | {span:.0f} | {busy:.0f} | {tot['compile'][1]} | {tot['cache_read'][1]} | {tl:.0f} | "
            f"{tot['compile'][0]:.0f} | {busy - tl - tot['compile'][0]:.0f} |")


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("paths", nargs="+", help="a timeline; with --headline, LABEL=PATH for each run")
    p.add_argument("--top", type=int, default=40)
    p.add_argument("--cpu", action="store_true", help="rank files by CPU s, not wall s")
    p.add_argument("--headline", action="store_true", help="only the headline table, a row a run")
    a = p.parse_args()
    if a.headline:
        print("\n".join([HEADLINE, *(headline_row(load(path), label)
                                     for label, path in (x.split("=", 1) for x in a.paths))]))
    else:
        print(summarise(load(a.paths[0]), a.top, a.cpu))
