"""The printer's sub-stepped sample (`DiscretePrinter.step`) against its earlier formulation, in
the closed loop's shape: B rollouts vmapped inside one `lax.scan` of T samples.

Earlier (reference, below): per sub-step $a = E z + P_1 (b + f(z))$,
$z' = a + P_2 (f(a) - f(z))$ with full matrices. Now: $P_1 b$ once per sample and the zone
columns of $P_1$, $P_2$ only, since the nonlinear terms $f$ (radiation, recoat) act on the
zone rows. Same states to rounding (the largest difference is printed); CPU seconds are the
process's (all threads), less sensitive than wall seconds to other jobs; interleaved repeats.

    python benchmarks/printer_step_ab.py              # N = 16, B = 64 and 256, T = 3600
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx
import jax.numpy as jnp

from jthermo.closedloop import REALISTIC_EFFECTS
from jthermo.printer import DiscretePrinter, make_printer
from jthermo.printer.plant import PrinterState

HERE = Path(__file__).resolve().parent


def reference_step(dp: DiscretePrinter, x: PrinterState, u, d) -> PrinterState:
    """The earlier `DiscretePrinter.step` (no input delay), full matrices in every sub-step."""
    pr = dp.printer
    b = dp.Bp @ pr._power(u) + dp.bs * d.ambient + dp.Bl @ d.laser
    since = jnp.where(d.recoat > 0.5, 0.0, x.since)
    E, P1, P2 = dp.disc.E, dp.disc.P1, dp.disc.P2
    h = pr.ts / dp.m

    def sub(z, j):
        t = since + j * h
        n0 = b + pr._nonlinear(z, t, d.ambient)
        a = E @ z + P1 @ n0
        n1 = b + pr._nonlinear(a, t + h, d.ambient)
        return a + P2 @ (n1 - n0), None

    z, _ = jax.lax.scan(sub, x.z, jnp.arange(dp.m, dtype=x.z.dtype))
    return PrinterState(z=z, buffer=x.buffer, since=since + pr.ts)


def scan_of(step, T: int):
    @eqx.filter_jit
    def run(dp, xs, u, d):
        def body(x, k):
            x = jax.vmap(lambda xi, ui: step(dp, xi, ui, d))(x, u)
            return x, x.z[:, : dp.printer.zones]
        return jax.lax.scan(body, xs, jnp.arange(T))[1]
    return run


def _load() -> str:
    return Path("/proc/loadavg").read_text().split()[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", default="64,256")
    ap.add_argument("--duration", type=int, default=3600)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(HERE / "results" / "printer_step_ab.md"))
    args = ap.parse_args()
    pr = make_printer(args.zones, REALISTIC_EFFECTS, powder="PA12", seed=0)
    dp = pr.discretise()
    d = pr.default_disturbance()
    rows = []
    for B in (int(b) for b in args.rollouts.split(",")):
        xs = jax.tree.map(lambda a, B=B: jnp.broadcast_to(a, (B, *a.shape)), pr.initial_state())
        u = jax.random.uniform(jax.random.key(1), (B, pr.n_inputs), pr.capacity.dtype)
        runs = {"earlier": scan_of(reference_step, args.duration),
                "now": scan_of(DiscretePrinter.step, args.duration)}
        temps = {k: f(dp, xs, u, d) for k, f in runs.items()}   # compiles
        diff = float(jnp.max(jnp.abs(temps["earlier"] - temps["now"])))
        cpu: dict = {k: [] for k in runs}
        wall: dict = {k: [] for k in runs}
        load0 = _load()
        for _ in range(args.repeats):
            for k, f in runs.items():
                c0, w0 = time.process_time(), time.perf_counter()
                jax.block_until_ready(f(dp, xs, u, d))
                cpu[k].append(time.process_time() - c0)
                wall[k].append(time.perf_counter() - w0)
        row = {"B": B, "diff": diff, "load": f"{load0} / {_load()}",
               **{f"cpu_{k}": statistics.median(v) for k, v in cpu.items()},
               **{f"wall_{k}": statistics.median(v) for k, v in wall.items()}}
        print(row, flush=True)
        rows.append(row)
    lines = ["# Printer sample: zone-column sub-steps against the earlier full-matrix form", "",
             (f"`python benchmarks/printer_step_ab.py`: N = {args.zones}, T = {args.duration}, "
              f"{pr.discretise().m} sub-steps per sample, every closed-loop effect; median of "
              f"{args.repeats} interleaved repeats; 2 shared CPU cores (load: 1-minute average "
              "before / after)."), "",
             ("| B | CPU s earlier | CPU s now | CPU ratio | wall s earlier | wall s now | "
              "max abs difference of the zone temperatures, °C | load |"),
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['B']} | {r['cpu_earlier']:.2f} | {r['cpu_now']:.2f} | "
                     f"{r['cpu_earlier'] / r['cpu_now']:.2f} | {r['wall_earlier']:.2f} | "
                     f"{r['wall_now']:.2f} | {r['diff']:.1e} | {r['load']} |")
    Path(args.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
