"""`jthermo fit --model ss|greybox` from the shell at N = 4, 16, 19.

Records: a linear N-zone bed (`BedModel`, absolute °C, measured surroundings `w_0`), PRBS on every
heater, process noise and coloured (AR(1)) sensor noise, 6000 estimation + 3000 validation
samples, Ts = 1 s. N = 19 is a 16-zone bed plus three "areas": three more heated bodies whose
heaters reach a third of the bed each, with their own sensors. Each fit runs in a fresh process
(`/usr/bin/time -v .venv/bin/jthermo fit est.csv --model M --validation val.csv --json out.json`):
cold wall time (compilation included) and peak RSS ("Maximum resident set size"), next to the
validation fit of the true (noise-free) model. `uptime` is recorded: the machine is shared.

Usage:
    python benchmarks/identification_scale.py [--n 4 16 19] [--families ss greybox] [--seed 0]

Writes `benchmarks/results/identification_scale.md` (and `.json`).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
T_EST, T_VAL, TS = 6000, 3000, 1.0
NOISE_STD, NOISE_POLE, PROCESS_STD = 0.1, 0.7, 0.01


def bed_plant(N: int, seed: int = 0):
    """The true linear bed: `(capacity, loss, gain)` (J/K, W/K, W), N zones (N = 19: 16 + 3 areas)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, N, 0]))
    n_zone = 16 if N == 19 else N
    rows = max(1, int(np.floor(np.sqrt(n_zone))))
    cols = int(np.ceil(n_zone / rows))
    P = np.stack([np.arange(n_zone) // cols, np.arange(n_zone) % cols], 1).astype(float)
    d2 = ((P[:, None] - P[None]) ** 2).sum(-1)
    capacity = rng.uniform(800.0, 1200.0, N)
    tau = rng.uniform(60.0, 200.0, N)                  # time constants C/G in s
    loss = capacity / tau
    G = np.full((N, N), 0.0)
    G[:n_zone, :n_zone] = np.exp(-d2 / 0.8)
    for a in range(N - n_zone):                         # areas: own body + a third of the bed
        part = np.arange(n_zone) * (N - n_zone) // n_zone == a
        G[n_zone + a, n_zone + a] = 1.0
        G[:n_zone, n_zone + a] = 0.15 * part
        G[n_zone + a, :n_zone] = 0.05 * part
    G = np.maximum(G, 0.005)
    # full power holds each zone about 60 K above the surroundings
    gain = G * (60.0 * loss / G.sum(1))[:, None]
    return capacity, loss, gain


def prbs(T: int, N: int, rng) -> np.ndarray:
    """Heater power fractions in {0.2, 0.8}, random holds of 5..40 samples, per heater."""
    u = np.empty((T, N))
    for j in range(N):
        level, t = rng.integers(0, 2), 0
        while t < T:
            hold = int(rng.integers(5, 41))
            u[t:t + hold, j] = 0.8 if level else 0.2
            t, level = t + hold, 1 - level
    return u


def simulate(plant, u, surr, x0, rng=None):
    capacity, loss, gain = plant
    from jthermo.models.greybox import BedModel

    ss = BedModel.from_physical(capacity, loss, gain, TS).to_statespace()
    A, B, Bw = (np.asarray(m) for m in (ss.A, ss.B, ss.Bw))
    x = np.empty((len(u), len(loss)))
    x[0] = x0
    for k in range(len(u) - 1):
        x[k + 1] = A @ x[k] + B @ u[k] + Bw[:, 0] * surr[k]
        if rng is not None:
            x[k + 1] += PROCESS_STD * rng.standard_normal(len(loss))
    return x


def record(N: int, T: int, seed: int, split: int):
    """One record `(IOData, noise-free y)`: starts at its steady state under the first input."""
    from jthermo.data import from_arrays

    plant = bed_plant(N, seed)
    rng = np.random.default_rng(np.random.SeedSequence([seed, N, split]))
    u = prbs(T, N, rng)
    surr = 25.0 + 1.5 * np.sin(2 * np.pi * np.arange(T) / 2500.0 + split) \
        + 0.05 * rng.standard_normal(T)
    capacity, loss, gain = plant
    x0 = surr[0] + gain @ u[0] / loss
    x = simulate(plant, u, surr, x0, rng)
    clean = simulate(plant, u, surr, x0)
    e = rng.standard_normal((T, N))
    v = np.empty((T, N))
    v[0] = NOISE_STD * e[0]
    for k in range(1, T):
        v[k] = NOISE_POLE * v[k - 1] + NOISE_STD * np.sqrt(1 - NOISE_POLE ** 2) * e[k]
    return from_arrays(u, x + v, TS, surr[:, None]), clean


def true_fit(N: int, seed: int, val) -> float:
    """Validation fit % of the true model (noise-free, initial state estimated as for a fit)."""
    from jthermo.models.greybox import BedModel
    from jthermo.validate import compare

    capacity, loss, gain = bed_plant(N, seed)
    return compare(BedModel.from_physical(capacity, loss, gain, TS), val)["mean_fit_percent"]


def run_cli(est: Path, val: Path, family: str, out: Path) -> dict:
    cmd = ["/usr/bin/time", "-v", str(ROOT / ".venv" / "bin" / "jthermo"), "fit", str(est),
           "--model", family, "--validation", str(val), "--json", str(out)]
    env = dict(os.environ)
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1800)
    wall = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)", p.stderr)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    secs = None
    if wall:
        h, m, s = wall.groups()
        secs = (int(h or 0) * 60 + int(m)) * 60 + float(s)
    row = {"exit": p.returncode, "wall_s": secs,
           "peak_rss_mb": int(rss.group(1)) / 1024 if rss else None}
    if p.returncode == 0 and out.exists():
        rep = json.loads(out.read_text())
        row.update(fit=rep["mean_fit_percent"], orders=rep["orders"], converged=rep["converged"])
    else:
        row["error"] = (p.stderr.strip().splitlines() or [""])[0][:200]
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[4, 16, 19])
    ap.add_argument("--families", nargs="+", default=["greybox", "ss"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=str(RESULTS / "identification_scale"))
    args = ap.parse_args(argv)
    from jthermo.data import save_csv

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for N in args.n:
            est, _ = record(N, T_EST, args.seed, 1)
            val, _ = record(N, T_VAL, args.seed, 2)
            pe, pv = Path(tmp) / f"est{N}.csv", Path(tmp) / f"val{N}.csv"
            save_csv(est, pe)
            save_csv(val, pv)
            truth = true_fit(N, args.seed, val)
            for fam in args.families:
                load = os.getloadavg()[0]
                row = {"N": N, "family": fam, "true_fit": truth, "load1": load,
                       **run_cli(pe, pv, fam, Path(tmp) / f"{fam}{N}.json")}
                row["gap"] = None if "fit" not in row else truth - row["fit"]
                rows.append(row)
                print(json.dumps(row), flush=True)
    uptime = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    lines = ["# Identification at scale: `jthermo fit` from the shell", "",
             f"`python benchmarks/identification_scale.py --n {' '.join(map(str, args.n))} "
             f"--families {' '.join(args.families)} --seed {args.seed}`; {T_EST} estimation + "
             f"{T_VAL} validation samples, Ts = {TS} s, linear bed, AR(1) sensor noise "
             f"(std {NOISE_STD}, pole {NOISE_POLE}), measured surroundings. Cold: one process "
             f"per fit, compilation included. Shared 2-core machine; uptime at the end: "
             f"`{uptime}` (load1 column: at the start of each fit).", "",
             "| N | family | exit | wall s | peak RSS MB | fit % | true fit % | gap | converged | "
             "orders | load1 |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f = (lambda v, nd=2: "—" if v is None else f"{v:.{nd}f}")
        lines.append(f"| {r['N']} | {r['family']} | {r['exit']} | {f(r['wall_s'], 1)} | "
                     f"{f(r['peak_rss_mb'], 0)} | {f(r.get('fit'))} | {f(r['true_fit'])} | "
                     f"{f(r.get('gap'))} | {r.get('converged', '—')} | {r.get('orders', r.get('error', ''))} | "
                     f"{r['load1']:.1f} |")
    Path(args.out + ".md").write_text("\n".join(lines) + "\n")
    Path(args.out + ".json").write_text(json.dumps({"rows": rows, "uptime": uptime}, indent=1))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
