"""State space against jax-sysid, cold with cold and warm with warm.

Same W1 records as `benchmarks/identification.py` (`../shared/bench/workloads.py`, T = 6000
estimation + 6000 validation samples, N = 4 and 16 zones, fit % = validation simulation fit
from rest, the oracle = the noise-free truth). Every (tool, configuration, N) runs in a fresh
process: `cold` = the first fit call (JAX compilation included; imports and data excluded, for
both tools), `warm` = a second fit call in the same process on the same data.

jthermo: `fit(data, "ss", (N,))` with its defaults (what `jthermo fit --model ss` does with the
order given; simulation focus by default; operating point chosen automatically).

jax-sysid (`LinearModel(N, N, N)`, L-BFGS on the simulation error), configured as its README and
`examples/dynamic/example_linear.py` recommend: inputs and outputs standard-scaled
(`jax_sysid.utils.standard_scale`), `loss(rho_x0=1e-3, rho_th=1e-2)`,
`optimization(adam_epochs=0, lbfgs_epochs=1000)` ("doc"); next to it the configuration of the
earlier benchmark (unscaled data, "unscaled") and variants searched for its best fit (weaker
regularisation, more L-BFGS epochs, a few seeds). Its second call re-initialises the same model
object and fits again (jax-sysid builds its jitted functions inside `fit`, so it recompiles).
jax-sysid 1.1.0 pins jax <= 0.4.31: it runs in its own environment (`--peer-python`, default `.venv-peers`), jthermo in
the project's (jax 0.10): each tool on the JAX its authors support.

Usage:
    make bench-peers   # .venv-peers from benchmarks/requirements-peers.txt (once)
    python benchmarks/peers_fair.py [--peer-python .venv-peers/bin/python]
        [--n 4 16] [--configs doc unscaled ...] [--out benchmarks/results/peers_fair]
    python benchmarks/peers_fair.py --from-log LOG   # the table of the rows a run printed
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")   # as identification.py: one BLAS thread for every tool

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from peers import SYSID_CONFIGS, sysid_fit, sysid_sim_from_rest  # noqa: E402



def _data(N: int):
    from identification import T, load_workloads

    W = load_workloads()
    est, val = W.estimation_validation(N, T, 0)
    oracle = W.fit_percent(val["y"], val["y_clean"])
    return W, est, val, oracle


def child(tool: str, config: str, N: int, warm: bool = True) -> dict:
    """One fresh process: cold call, warm call (unless not `warm`), validation fit from rest.
    `*_s` wall, `*_cpu` user + system CPU s of the process (all threads) around the fit call."""
    from identification import timed

    W, est, val, oracle = _data(N)
    row = {"tool": tool, "config": config, "N": N, "oracle": oracle, "warm_s": None,
           "warm_cpu": None}
    if tool == "jax-sysid":
        fit_once = (lambda: sysid_fit(est, N, config))
    else:
        import jax

        jax.config.update("jax_enable_x64", True)
        from identification import simulate_from_rest

        from jthermo.data import from_arrays
        from jthermo.identify.fit import fit

        data = from_arrays(est["u"], est["y"])
        fit_once = (lambda: jax.block_until_ready(fit(data, "ss", (N,), seed=0)))
    for key in ("cold", "warm")[:2 if warm else 1]:
        res, row[f"{key}_s"], row[f"{key}_cpu"] = timed(fit_once)
    if tool == "jax-sysid":
        yhat = sysid_sim_from_rest(*res, val["u"])
    else:
        row["converged"] = bool(res.converged)
        yhat = simulate_from_rest(res.model, val["u"])
    fitp = W.fit_percent(val["y"], yhat)
    row["fit"] = fitp if np.isfinite(fitp) else None
    row["load1"] = os.getloadavg()[0]
    return row


def run_child(python: str, tool: str, config: str, N: int, timeout: float,
              cold_only: bool = False) -> dict:
    cmd = ["nice", "-n", "5", python, str(Path(__file__).resolve()), "--child", tool, config,
           str(N)] + (["--cold-only"] if cold_only else [])
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT,
                           check=False)
    except subprocess.TimeoutExpired:
        return {"tool": tool, "config": config, "N": N, "error": f"timeout {timeout:.0f} s"}
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode != 0 or not lines:
        return {"tool": tool, "config": config, "N": N,
                "error": (p.stderr.strip().splitlines() or ["?"])[-1][:200]}
    return json.loads(lines[-1])


def report(rows: list[dict], args, uptime: str) -> list[str]:
    f = (lambda v, nd=1: "—" if v is None else f"{v:.{nd}f}")
    lines = ["# State space vs jax-sysid, cold with cold and warm with warm", "",
             (f"`python benchmarks/peers_fair.py --n {' '.join(map(str, args.n))} --configs "
             f"{' '.join(args.configs)}` (jax-sysid in its own environment: jax-sysid 1.1.0 pins "
             "jax <= 0.4.31; jthermo on jax 0.10). W1 records of `identification.py`, T = 6000 + "
             "6000, fit % = validation simulation from rest. One fresh process per row: cold = "
             "first fit call (compilation included), warm = second call in that process. "
             "Speed-up = jax-sysid s / jthermo s, cold / warm, by wall and by CPU s (user + system "
             "of the process, all threads; the load-robust figure). Children run with `nice -n "
             "5`. Shared 2-core machine (load1 at "
             f"the end of each row; wall times inflated by the load); uptime "
             f"{'when rendered from the run log' if args.from_log else 'at the end'}: `{uptime}`."),
             "" if not args.from_log else
             f"Rendered with `--from-log {Path(args.from_log).name}`: the rows of that log only (a "
             "configuration absent at some N was not run there; warm `—`: the child ran with "
             "`--cold-only`).",
             "", ("| N | tool | configuration | cold s (CPU s) | warm s (CPU s) | fit % | oracle % "
                  "| speed-up cold / warm, wall | by CPU s | load1 |"),
             "|---|---|---|---|---|---|---|---|---|---|"]

    def ratio(r, ref, unit):
        return " / ".join("—" if r.get(f"{k}_{unit}") is None or not ref.get(f"{k}_{unit}")
                          else f"{r[f'{k}_{unit}'] / ref[f'{k}_{unit}']:.1f}×"
                          for k in ("cold", "warm"))

    for r in rows:
        ref = next((q for q in rows if q["tool"] == "jthermo" and q["N"] == r["N"]
                    and "cold_s" in q), None)
        if "error" in r:
            lines.append(f"| {r['N']} | {r['tool']} | {r['config']} | — | — | — | — | "
                         f"{r['error']} | — | — |")
            continue
        speed = cpu = "—"
        if r["tool"] != "jthermo" and ref:
            speed, cpu = ratio(r, ref, "s"), ratio(r, ref, "cpu")
        lines.append(f"| {r['N']} | {r['tool']} | {r['config']} | {f(r['cold_s'])} "
                     f"({f(r.get('cold_cpu'))}) | {f(r['warm_s'])} ({f(r.get('warm_cpu'))}) | "
                     f"{f(r['fit'])} | {f(r['oracle'])} | {speed} | {cpu} | {r['load1']:.1f} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", nargs=3, metavar=("TOOL", "CONFIG", "N"), help=argparse.SUPPRESS)
    ap.add_argument("--peer-python", default=str(ROOT / ".venv-peers" / "bin" / "python"),
                    help="python of an environment with jax-sysid installed (`make bench-peers`)")
    ap.add_argument("--n", type=int, nargs="+", default=[4, 16])
    ap.add_argument("--configs", nargs="+", default=["doc", "unscaled"],
                    choices=sorted(SYSID_CONFIGS))
    ap.add_argument("--timeout", type=float, default=1800.0, help="s per process")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "peers_fair"))
    ap.add_argument("--cold-only", action="store_true",
                    help="no warm call (the rows' warm column stays empty)")
    ap.add_argument("--no-jthermo", action="store_true",
                    help="peer rows only (to be rendered with --from-log beside a jthermo row)")
    ap.add_argument("--from-log", type=Path, default=None,
                    help="render the rows a run printed (one JSON object a line) instead of running")
    args = ap.parse_args(argv)
    if args.child:
        tool, config, n = args.child
        print(json.dumps(child(tool, config, int(n), warm=not args.cold_only)), flush=True)
        return 0
    rows = []
    if args.from_log is not None:
        rows = [json.loads(ln) for ln in args.from_log.read_text().splitlines()
                if ln.startswith('{"tool"')]
        args.n = sorted({r["N"] for r in rows})
        args.configs = list(dict.fromkeys(r["config"] for r in rows if r["tool"] != "jthermo"))
    for N in ([] if args.from_log is not None else args.n):
        runs = [("jthermo", "default", sys.executable)] * (not args.no_jthermo) + \
            [("jax-sysid", c, args.peer_python) for c in args.configs]
        for tool, config, python in runs:
            print(f"[peers_fair] N={N} {tool} {config} ...", file=sys.stderr, flush=True)
            rows.append(run_child(python, tool, config, N, args.timeout, args.cold_only))
            print(json.dumps(rows[-1]), flush=True)
    uptime = subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    out = Path(args.out)
    out.with_suffix(".json").write_text(json.dumps({"rows": rows, "uptime": uptime}, indent=1))
    out.with_suffix(".md").write_text("\n".join(report(rows, args, uptime)) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
