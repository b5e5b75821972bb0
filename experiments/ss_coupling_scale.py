"""The state-space gap to the true model at N = 4 .. 19 zones — structure, not steps.

On the records of `benchmarks/identification_scale.py`, `fit_statespace` with the default
options (automatic order, simulation focus, operating point "auto") and `coupling` "auto"
(the default: with one state per output, diagonal A unless a hold-out on the last third of the
estimation record favours full A), "diagonal" or "full" (the earlier default: N4SID starts,
full A). In-process (warm imports, compilation included): wall and process CPU seconds
(`time.process_time`, all threads); validation simulation fit next to the true model's.
`--seeds 1 2` checks records that were not looked at while choosing the method.
`--real` compares the couplings on the W1 workload (N = 4) and the real recordings of
`experiments/identify.py` (its options and validation: `identify.evaluate`; cases as
`ss_focus_scale.real_cases`), where only models with n = ny are affected.

Writes `experiments/results/ss_coupling_scale.md`
(`ss_coupling_scale_real.md` with `--real`).

Usage: python experiments/ss_coupling_scale.py [--n 4 9 16 19] [--seeds 0] [--coupling auto]
       python experiments/ss_coupling_scale.py --real [--coupling full auto]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "experiments"))


def row(N: int, seed: int, coupling: str) -> str:
    import identification_scale as S

    from jthermo.identify.statespace import fit_statespace
    from jthermo.validate import compare

    est, _ = S.record(N, S.T_EST, seed, 1)
    val, _ = S.record(N, S.T_VAL, seed, 2)
    truth = S.true_fit(N, seed, val)
    load = os.getloadavg()[0]
    t, c = time.perf_counter(), time.process_time()
    r = fit_statespace(est, coupling=coupling)
    sec, cpu = time.perf_counter() - t, time.process_time() - c
    fit = compare(r.model, val)["mean_fit_percent"]
    hold = r.extra.get("coupling_holdout")
    hold = "—" if hold is None else f"{hold['diagonal']:.0f} / {hold['full']:.0f}"
    return (f"| {N} | {seed} | {coupling} | {r.orders['n']} | {r.extra['coupling']} | {hold} | "
            f"{sec:.1f} | {cpu:.1f} | {load:.1f} | {r.converged} | {fit:.2f} | {truth:.2f} | "
            f"{truth - fit:.2f} |")


def real_cases():
    """(name, orders, est, val): W1 N = 4 (ss 4 and automatic) and `ss_focus_scale.real_cases`."""
    import identify as I
    from ss_focus_scale import real_cases as recordings

    from jthermo.data import from_arrays

    e, v = I._workloads().estimation_validation(4, 6000, 0)
    est, val = from_arrays(e["u"], e["y"]), from_arrays(v["u"], v["y"])
    yield "W1 N=4", (4,), est, val
    yield "W1 N=4", None, est, val
    yield from recordings()


def real_rows(couplings) -> list[str]:
    import identify as I

    lines = ["| data | n | coupling | wall s | CPU s | load1 | fit % per output | mean fit % |",
             "|---|---|---|---|---|---|---|---|"]
    for name, orders, est, val in real_cases():
        for coupling in couplings:
            load = os.getloadavg()[0]
            c = time.process_time()
            r = I.evaluate(name, "ss", orders, est, val, coupling=coupling)
            cpu = time.process_time() - c
            fits = ", ".join(f"{f:.1f}" for f in r.get("fit", []))
            n = r.get("orders", {}).get("n", "—")
            lines.append(f"| {name} | {n}{'' if orders else ' (auto)'} | {coupling} | "
                         f"{r.get('seconds', float('nan')):.1f} | "
                         f"{cpu:.1f} | {load:.1f} | {fits or r.get('error', '')} | "
                         f"{r.get('mean_fit', float('nan')):.2f} |")
            print(lines[-1], flush=True)
    return lines


def main(argv=None) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, nargs="+", default=[4, 9, 16, 19])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--coupling", nargs="+", default=["auto"])
    ap.add_argument("--real", action="store_true", help="W1 and the real recordings")
    args = ap.parse_args(argv)
    if args.real:
        cmd = "python experiments/ss_coupling_scale.py --real --coupling " + " ".join(args.coupling)
        lines = [f"# ss structure on W1 and real recordings (`{cmd}`)", ""]
        lines += real_rows(args.coupling)
        return _write(lines, "ss_coupling_scale_real.md")
    cmd = ("python experiments/ss_coupling_scale.py --n " + " ".join(map(str, args.n))
           + " --seeds " + " ".join(map(str, args.seeds)) + " --coupling "
           + " ".join(args.coupling))
    lines = [f"# ss structure at scale (`{cmd}`)", "",
             ("| N | seed | coupling | n | chosen | hold-out sim. error diag / full | wall s | "
              "CPU s | load1 | converged | val fit % | true fit % | gap |"),
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for N in args.n:
        for seed in args.seeds:
            for coupling in args.coupling:
                lines.append(row(N, seed, coupling))
                print(lines[-1], flush=True)
    return _write(lines, "ss_coupling_scale.md")


def _write(lines: list[str], name: str) -> int:
    up = subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    lines += ["", (f"uptime at the end: `{up}` (shared 2-core machine: wall times are inflated "
                   "by the load; CPU s is the load-robust figure)")]
    (ROOT / "experiments" / "results" / name).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
