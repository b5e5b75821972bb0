"""`jthermo diagnose` on the README tour's kind of record at N = 1 ... 16 zones: wall and CPU
time, peak memory, what it names and whether the joint (coupled) fit was kept (issues 13, 14).

Each N: `jthermo generate` writes a one-hour estimation and a 30-min validation record of one
printer (`--seed 1` / `--seed 2`, printer seed 0) with lateral conduction, radiation and a
heater lag concealed (the latency benchmark's effects), then `jthermo diagnose` runs in a fresh
process on a warm compilation cache (a first diagnosis of the same N fills it, untimed, unless
`--cold`), killed after `--timeout` seconds.

    .venv/bin/python experiments/diagnose_zone_scaling.py --zones 1,2,4,6,9 [--timeout 900]

Writes `experiments/results/diagnose_zone_scaling.md` and `.json`.
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

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from common import load1  # noqa: E402

HERE = Path(__file__).resolve().parent
EFFECTS = "lateral_conduction,radiative_loss,heater_lag"
TRUTH = set(EFFECTS.split(","))



def _run(argv, env, timeout) -> dict:
    """One `jthermo` process: wall s, CPU s (user + system) and its peak resident memory."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load, t0 = load1(), time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-m", "jthermo.cli", *argv, "--quiet"], env=env,
                           capture_output=True, text=True, timeout=timeout, check=False)
        rc, err = r.returncode, (r.stderr.strip().splitlines() or [""])[-1]
    except subprocess.TimeoutExpired:
        rc, err = None, f"killed after {timeout} s"
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": round(time.perf_counter() - t0, 1), "cpu_s": round(cpu, 1), "rc": rc,
            "error": err if rc != 0 else "", "load": load,
            # RUSAGE_CHILDREN's peak is the largest child's so far: zones run in increasing order
            "peak_rss_mb_so_far": round(after.ru_maxrss / 1024)}


def one(n: int, tmp: Path, env: dict, timeout: float, cold: bool) -> dict:
    d = tmp / f"n{n}"
    d.mkdir()
    for name, dur, seed in (("est.csv", "3600", "1"), ("val.csv", "1800", "2")):
        _run(["generate", "--zones", str(n), "--effects", EFFECTS, "--duration", dur,
              "--seed", seed, "--out", str(d / name)], env, timeout)
    argv = ["diagnose", str(d / "est.csv"), "--validation", str(d / "val.csv"), "--json", str(d / "d.json")]
    if not cold:
        _run(argv, env, timeout)              # fills the cache for this N (untimed)
    row = {"zones": n, **_run(argv, env, timeout)}
    if row["rc"] == 0:
        rep = json.loads((d / "d.json").read_text())
        aug = rep.get("augmented") or {}
        named = [f["mechanism"] for f in rep.get("findings", [])]
        truth = TRUTH - ({"lateral_conduction"} if n == 1 else set())   # one zone: no neighbour
        row.update(n_concealed=len(truth),
                   confidence=[round(f["confidence"], 3) for f in rep.get("findings", [])],
                   rivals=[f.get("rivals", []) for f in rep.get("findings", [])], compile_s=rep.get("compile_s"), run_s=rep.get("run_s"), named=named,
                   right=sorted(truth & set(named)), wrong=sorted(set(named) - truth),
                   baseline_fit=round(rep["baseline"]["mean_fit_percent"], 2),
                   augmented_fit=round(aug.get("mean_fit_percent", float("nan")), 2),
                   fit_kind=aug.get("fit", ""),
                   negative_lr_additions=sum(c["estimation_lr"] < 0 for c in rep.get("combinations", [])),
                   additions=len(rep.get("combinations", [])))
    print(row, flush=True)
    return row


def _named(r) -> str:
    """`mechanism confidence [rivals]`, one per finding (rows made before they were recorded:
    the names alone)."""
    conf, riv = r.get("confidence"), r.get("rivals")
    if conf is None:
        return ", ".join(r["named"])
    return ", ".join(f"{m} {c:.3f}" + (f" [rivals: {' '.join(v)}]" if v else "")
                     for m, c, v in zip(r["named"], conf, riv))


def write(rows, args, path: Path) -> None:
    lines = ["# `jthermo diagnose` against the number of zones", "",
             f"Made by `python experiments/diagnose_zone_scaling.py --zones {args.zones} --timeout "
             f"{args.timeout:g}{' --cold' if args.cold else ''}`."
             " Records: `jthermo generate --zones N --effects " + EFFECTS + " --duration 3600 "
             "--seed 1` (estimation) and `--duration 1800 --seed 2` (validation), one printer. "
             + ("Cold: an empty compilation cache." if args.cold else
                "Warm: a second process on the cache the first diagnosis of that N filled.")
             + " 2 shared CPU cores: the 1-min load is beside each row.", "",
             "| N | wall s | CPU s | compile / run s | peak RSS MB (so far) | named | concealed named | "
             "other names | baseline → augmented fit % | augmented model | additions with LR < 0 | load |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["rc"] != 0:
            lines.append(f"| {r['zones']} | {r['wall_s']} | {r['cpu_s']} | | {r['peak_rss_mb_so_far']} | "
                         f"{r['error']} | | | | | | {r['load']} |")
            continue
        lines.append(f"| {r['zones']} | {r['wall_s']} | {r['cpu_s']} | {r['compile_s']} / {r['run_s']} | "
                     f"{r['peak_rss_mb_so_far']} | {_named(r) or '-'} | "
                     f"{len(r['right'])}/{r.get('n_concealed', 3 - (r['zones'] == 1))} | {', '.join(r['wrong']) or '-'} | {r['baseline_fit']} → "
                     f"{r['augmented_fit']} | {r['fit_kind']} | {r['negative_lr_additions']}/{r['additions']} | "
                     f"{r['load']} |")
    path.with_suffix(".md").write_text("\n".join(lines) + "\n")
    path.with_suffix(".json").write_text(json.dumps(rows, indent=1) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zones", default="1,2,4,6,9")
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--cold", action="store_true")
    ap.add_argument("--rewrite", action="store_true", help="rewrite the table from the JSON rows")
    args = ap.parse_args(argv)
    rows = []
    out = HERE / "results" / "diagnose_zone_scaling"
    if args.rewrite:
        write(json.loads(out.with_suffix(".json").read_text()), args, out)
        return
    with tempfile.TemporaryDirectory() as tmp:
        env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
        env.pop("JTHERMO_NO_CACHE", None)
        env["JTHERMO_CACHE_DIR"] = str(Path(tmp) / "cache")
        for n in sorted(int(z) for z in args.zones.split(",")):
            rows.append(one(n, Path(tmp), env, args.timeout, args.cold))
            write(rows, args, out)


if __name__ == "__main__":
    main()
