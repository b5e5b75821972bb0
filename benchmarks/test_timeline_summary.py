"""Per-file wall time and per-worker balance of a test run recorded by `test_timeline.py`.

    python benchmarks/test_timeline_summary.py out.jsonl [--top 40] [--cpu]
A file's time runs from its first test's start to its last test's end (module fixtures and
the compiled-code release between modules fall inside or between them); a worker's idle tail
is the time from its last test's end to the last test's end on any worker."""
import argparse
import json
from collections import defaultdict


def load(path):
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def summarise(rows, top, by_cpu=False):
    if any(r["worker"] != "main" for r in rows):     # the xdist controller echoes its workers' tests
        rows = [r for r in rows if r["worker"] != "main"]
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
    out += ["", "last files to start:"]
    for name, (s, e, n, w, _) in sorted(files.items(), key=lambda kv: kv[1][0])[-6:]:
        out.append(f"  {name} ({w}) {s - t0:.1f} -> {e - t0:.1f}")
    return "\n".join(out)


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("path")
    p.add_argument("--top", type=int, default=40)
    p.add_argument("--cpu", action="store_true", help="rank files by CPU s, not wall s")
    a = p.parse_args()
    print(summarise(load(a.path), a.top, a.cpu))
