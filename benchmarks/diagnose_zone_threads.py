"""Would the per-zone candidate fits run faster split over threads? `fitting.fit_zones` fits its
problems one after another in one compiled program (`lax.map`), which on two cores leaves one
core mostly idle (the warm run's CPU is ~1.3x its wall time). Here the diagnosis's own
`fit_zones` calls on the latency record (`diagnose_profile.write_record`: N = 4, one-hour
estimation and half-hour validation records) are run as they are and again as `--shares` equal shares (problems dealt round-robin), each
share's call in a thread of its own (after one compiling call), comparing wall s and results.

A second look at a rejected split (two threads over the joint fits deadlocked:
one call per problem, two threads, a hang). Measured 2026-11-28: the per-zone fits split well
(see the results file), but the same split of the joint fits (`fitting.fit_joint`) hung, also
with `XLA_FLAGS=--xla_cpu_multi_thread_eigen=false`. The cause, found later that day (the
deadlock record): `masked_lm`'s batched LU waited on XLA's pool from a pool thread; it now
factors one matrix at a time and `fitting` splits every call into shares itself
(`fitting._run_spread`). This script keeps its watchdog (`--watchdog` s, then the stacks and
exit status 1) and splits the calls it captures explicitly (`JTHERMO_FIT_THREADS=1` inside).

    python benchmarks/diagnose_zone_threads.py [--shares 2]

Writes `benchmarks/results/diagnose_zone_threads.md`.
"""

from __future__ import annotations

import argparse
import faulthandler
import os
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np
from diagnose_profile import write_record

from jthermo import data, runtime
from jthermo.diagnose import fitting as F
from jthermo.diagnose import select as S

HERE = Path(__file__).resolve().parent


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--shares", type=int, default=2)
    ap.add_argument("--watchdog", type=float, default=900.0)
    args = ap.parse_args(argv)
    faulthandler.dump_traceback_later(args.watchdog, exit=True)
    os.environ["JTHERMO_FIT_THREADS"] = "1"          # the split is this script's own
    runtime.enable_cache()
    k, rows = args.shares, []
    whole_call = F.fit_zones

    def in_shares(theta0, mask, on, per, shared, lay, n_iter, n_active=None, budget=None):
        B = theta0.shape[0]
        budget = np.full(B, n_iter) if budget is None else np.asarray(budget)
        call = lambda: jax.block_until_ready(whole_call(theta0, mask, on, per, shared, lay, n_iter, n_active, budget))
        call()                                     # compiled (or read from the cache)
        t = time.perf_counter()
        ref = call()
        t_whole = time.perf_counter() - t
        order = np.argsort(-budget, kind="stable")
        size = -(-B // k)
        parts = []
        for j in range(k):
            ix = order[j::k]
            pad = size - ix.size
            parts.append((np.concatenate([ix, np.repeat(ix[-1:], pad)]),
                          np.concatenate([budget[ix], np.zeros(pad, budget.dtype)]), ix.size))

        def share(p):
            ix, b, _ = p
            take = lambda a: jnp.asarray(np.asarray(a)[ix])
            return jax.block_until_ready(whole_call(take(theta0), take(mask), take(on),
                                                    {key: take(v) for key, v in per.items()},
                                                    shared, lay, n_iter, n_active, b))

        share(parts[0])                            # compiled once, before the threads
        t = time.perf_counter()
        with ThreadPoolExecutor(k) as pool:
            outs = list(pool.map(share, parts))
        t_split = time.perf_counter() - t
        diff = 0.0
        for r, *o in zip(ref, *outs):
            full = np.empty_like(np.asarray(r))
            for (ix, _, real), x in zip(parts, o):
                full[ix[:real]] = np.asarray(x)[:real]
            diff = max(diff, float(np.nanmax(np.abs(full - np.asarray(r)))))
        rows.append((B, int((budget > 0).sum()), t_whole, t_split, diff))
        return ref

    with tempfile.TemporaryDirectory() as tmp:
        e, v = write_record(Path(tmp))
        est, val = data.load(e), data.load(v)
        S.fit_zones = in_shares
        try:
            S.diagnose(est, val)
        finally:
            S.fit_zones = whole_call
    lines = [f"# Per-zone fits split over threads, N = 4, {k} shares", "",
             (f"Made by `python benchmarks/diagnose_zone_threads.py --shares {k}"
              f"`; {os.cpu_count()} CPUs, 1-minute load "
              f"{os.getloadavg()[0]:.2f} at the end; wall s of each warm call (after a compiling one)."), "",
             "| problems | with iterations | one call s | shares in threads s | ratio | largest difference |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {B} | {w} | {a:.2f} | {b:.2f} | {b / a:.2f} | {dd:.3g} |" for B, w, a, b, dd in rows]
    out = HERE / "results" / "diagnose_zone_threads.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
