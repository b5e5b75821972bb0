"""Why jthermo's fixed-order W1 fits end hundredths of a point below SIPPY's: both
models scored on the same two yardsticks, over several data seeds.

For each seed, family (ARMAX, OE, BJ at the W1 orders of `benchmarks/identification.py`, and
the N4SID subspace estimate, which has no V) and N:
jthermo's fit (`identification.jthermo_fit`, the NumPy PEM engine and the compiled one) and
SIPPY's (`identification._sippy_fit`, in the peers' environment, `make bench-peers`), each in a
fresh process. Columns: the validation simulation fit % from rest (the benchmark's figure) and
the prediction-error criterion that PEM minimises on the estimation record, $V =
\\frac{1}{T n_y}\\sum \\varepsilon^2$, $\\varepsilon_i = H_i^{-1}(y_i - \\sum_j G_{ij} u_j)$ from
rest (zero initial conditions), computed for both tools' models from their transfer functions
by the same `scipy.signal.lfilter` code. A model with the lower V on the estimation data is the
better PEM estimate; the validation fit then says how that carries over to new data.

    python benchmarks/peers_fit_gap.py --n 4 --seeds 0 1 2
    -> benchmarks/results/peers_fit_gap.md (and .json)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import identification as B  # noqa: E402

FAMILIES = ("armax", "oe", "bj", "n4sid")


def pem_cost(num, den, num_h, den_h, y: np.ndarray, u: np.ndarray) -> float:
    """$V$ of a MIMO model given as nested coefficient lists (powers of z, descending):
    `num[i][j] / den[i][j]` from input j to output i, noise filter `num_h[i] / den_h[i]`."""
    from scipy.signal import lfilter

    def tf(b, a, x):
        b, a = np.atleast_1d(np.asarray(b, float)).ravel(), np.atleast_1d(np.asarray(a, float)).ravel()
        n = max(len(a), len(b))
        b, a = np.r_[np.zeros(n - len(b)), b], np.r_[a, np.zeros(n - len(a))]
        return lfilter(b, a, x)

    eps = np.stack([tf(den_h[i], num_h[i], y[:, i] - sum(tf(num[i][j], den[i][j], u[:, j])
                                                           for j in range(u.shape[1])))
                    for i in range(y.shape[1])], axis=1)
    return float(np.mean(eps ** 2))


def _sippy_h(model, i: int):
    """SIPPY's noise filter of output i: its H is an (ny x 1) transfer function, one row per
    output (`NUMERATOR_H[i]`, `DENOMINATOR_H[i]` nest one list deeper)."""
    return (np.asarray(model.NUMERATOR_H[i], float).ravel(),
            np.asarray(model.DENOMINATOR_H[i], float).ravel())


def jthermo_child(family: str, N: int, seed: int, engine: str) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    from jthermo.data import from_arrays
    from jthermo.models import polynomial_numpy

    W = B.load_workloads()
    est, val = W.estimation_validation(N, B.T, seed)
    t0 = time.process_time()
    res = B.jthermo_fit(family, from_arrays(est["u"], est["y"]), N, engine=engine)
    cpu = time.process_time() - t0
    row = {"tool": B.jthermo_tool(engine) if family in B.ENGINE_FAMILIES else "jthermo",
           "fit": W.fit_percent(val["y"], B.simulate_from_rest(res.model, val["u"])), "cpu": cpu,
           "converged": bool(res.converged)}
    if polynomial_numpy.supported(res.model):
        row["V"] = float(np.mean(polynomial_numpy.residuals(res.model, est["y"], est["u"]) ** 2))
    return row


def sippy_child(family: str, N: int, seed: int) -> dict:
    W = B.load_workloads()
    est, val = W.estimation_validation(N, B.T, seed)
    t0 = time.process_time()
    model = B._sippy_fit(family, est, N)
    cpu = time.process_time() - t0
    row = {"tool": "SIPPY", "fit": W.fit_percent(val["y"], B._sippy_sim(model, family, val["u"])),
           "cpu": cpu}
    if family != "n4sid":
        hs = [_sippy_h(model, i) for i in range(N)]
        row["V"] = pem_cost(model.NUMERATOR, model.DENOMINATOR, [h[0] for h in hs],
                            [h[1] for h in hs], est["y"], est["u"])
    return row


def run(python: str, args: list[str], timeout: float) -> dict:
    cmd = ["nice", "-n", "5", python, str(Path(__file__).resolve()), "--child", *args]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode or not lines:
        return {"error": (p.stderr.strip().splitlines() or [f"exit {p.returncode}"])[-1][:160]}
    return json.loads(lines[-1])


def markdown(rows: list[dict], command: str) -> str:
    lines = ["# Fixed-order W1 fits: jthermo and SIPPY on the same yardsticks", "",
             "fit % = validation simulation fit from rest (the benchmark's figure); V = mean "
             "squared one-step prediction error on the estimation record from rest (the PEM "
             "criterion; for OE the simulation error), both tools' models through the same "
             "code (`peers_fit_gap.pem_cost`, `polynomial_numpy.residuals`). Δ = jthermo − "
             "SIPPY. CPU s of the fit call (first call in a fresh process: jthermo's compiled "
             "engine includes its compilation, no persistent cache). Load = 1-minute load "
             "average at the row's end (2 shared cores).", "", f"Command: `{command}`", "",
             "| family | N | seed | tool | fit % | V (est.) | Δfit (pt) | ΔV / V_SIPPY | CPU s | load | note |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    ref = {(r["family"], r["N"], r["seed"]): r for r in rows if r["tool"] == "SIPPY"}
    for r in rows:
        s = ref.get((r["family"], r["N"], r["seed"]), {})
        d_fit = d_v = "—"
        if r["tool"] != "SIPPY" and "fit" in s and "fit" in r:
            d_fit = f"{r['fit'] - s['fit']:+.4f}"
            if "V" in r and "V" in s:
                d_v = f"{(r['V'] - s['V']) / s['V']:+.2e}"
        fit = f"{r['fit']:.4f}" if "fit" in r else "—"
        V = f"{r['V']:.8f}" if "V" in r else "—"
        cpu = f"{r['cpu']:.2f}" if "cpu" in r else "—"
        lines.append(f"| {r['family'].upper()} | {r['N']} | {r['seed']} | {r['tool']} | {fit} | {V} "
                     f"| {d_fit} | {d_v} | {cpu} | {r['load']:.1f} | {r.get('error', '')} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=4)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=FAMILIES)
    ap.add_argument("--engines", nargs="+", default=["numpy", "jax"], choices=("jax", "numpy"))
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--out", type=Path, default=None,
                    help="default benchmarks/results/peers_fit_gap.md")
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        kind, fam, N, seed, *rest = args.child
        row = (jthermo_child(fam, int(N), int(seed), rest[0]) if kind == "jthermo"
               else sippy_child(fam, int(N), int(seed)))
        print(json.dumps(row), flush=True)
        return 0
    from jthermo.data import atomic_write_text

    out = args.out or ROOT / "benchmarks" / "results" / "peers_fit_gap.md"
    command = "python benchmarks/peers_fit_gap.py " + " ".join(argv or sys.argv[1:])
    rows = []
    for seed in args.seeds:
        for fam in args.families:
            engines = args.engines if fam in B.ENGINE_FAMILIES else ["jax"]
            jobs = [("jthermo", sys.executable, [e]) for e in engines]
            jobs.append(("sippy", str(B.PEERS_PYTHON), []))
            for kind, python, extra in jobs:
                print(f"[fit gap] N={args.n} seed {seed} {fam} {kind} {extra}", file=sys.stderr,
                      flush=True)
                r = run(python, [kind, fam, str(args.n), str(seed), *extra], args.timeout)
                r.setdefault("tool", "SIPPY" if not extra else
                             B.jthermo_tool(extra[0]) if fam in B.ENGINE_FAMILIES else "jthermo")
                rows.append({"family": fam, "N": args.n, "seed": seed, **r,
                             "load": os.getloadavg()[0]})
                atomic_write_text(out, markdown(rows, command))
                atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1))
    print(markdown(rows, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
