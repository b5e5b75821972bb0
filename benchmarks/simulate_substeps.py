"""Sub-steps of the printer in the recoat-free scenarios: the integration error of
`Printer.discretise(recoat=False)` (radiation alone, `SMOOTH_SUBSTEPS` sub-steps) and of the
earlier path (`substeps` = 10, the recoat term evaluated though no recoat happens) against a
fine-step reference (100 sub-steps), and what the run program costs with each.

Error: the true zone temperatures of B closed-loop rollouts of `pi_lambda` on the 16-zone
realistic printer, max and rms of |T - T_ref| over every sample, zone and rollout, and the
MSE figure `jthermo simulate` reports. Time: the lean program of `closedloop.run` (scenarios
drawn and metrics accumulated in one compiled call) at the command's size, second call
(compiled), CPU seconds of the process (user + system, all threads) beside the wall seconds
and the 1-minute load (2 shared cores).

    python benchmarks/simulate_substeps.py                       # B = 8 errors, B = 256 timing
    python benchmarks/simulate_substeps.py --time-rollouts 32 --duration 900 --out -   # quick
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
from common import finish, load, timed

HERE = Path(__file__).resolve().parent
NOISE = "sensor noise: white 0.05 °C (scenario) + 0.05 °C and AR(1) 0.1 °C (`sensor_noise`)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=8, help="rollouts for the error")
    ap.add_argument("--time-rollouts", type=int, default=256, help="rollouts for the timing")
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_substeps.md"))
    args = ap.parse_args()
    jax.config.update("jax_enable_x64", True)
    from jthermo import closedloop as cl
    from jthermo.closedloop import engine
    from jthermo.control.design import design
    from jthermo.printer import SMOOTH_SUBSTEPS, make_printer
    from jthermo.tune import printer_model

    def printer(m=10):
        return make_printer(args.zones, cl.REALISTIC_EFFECTS, powder="PA12", seed=0, substeps=m)

    base = printer()
    ctrl = design("pi_lambda", eqx.filter_jit(printer_model)(base))
    dense = eqx.filter_jit(lambda p, s: cl.rollouts(p, ctrl, s))
    load0 = load()
    lines = [(f"# Printer sub-steps in the recoat-free scenarios: N = {args.zones}, "
              f"T = {args.duration:g} s"), "",
             (f"`python benchmarks/simulate_substeps.py --rollouts {args.rollouts} "
              f"--time-rollouts {args.time_rollouts} --duration {args.duration:g} --seed "
              f"{args.seed}`; controller pi_lambda on the realistic printer; {NOISE}."), "",
             "## Integration error against 100 sub-steps", "",
             (f"{args.rollouts} rollouts, stored trajectories (`rollouts`: the full "
              "integration, recoat term kept); the recoat-free integration is that of a printer "
              f"with {SMOOTH_SUBSTEPS} sub-step(s), the recoat term being exactly zero without "
              "a recoat (equal to `recoat=False` to 1e-10: tests/closedloop/test_engine_substeps.py)."),
             "",
             "| scenario | integration | sub-steps | max abs dT °C | rms dT °C | mse | rel. mse change |",
             "|---|---|---|---|---|---|---|"]
    for kind in engine.RECOAT_FREE_KINDS:
        sc = cl.make_scenario(kind, base, args.duration, jax.random.key(args.seed),
                              n_rollouts=args.rollouts)
        ref = dense(printer(100), sc)
        mse_ref = float(jnp.mean((ref.y - ref.r) ** 2))
        lines.append(f"| {kind} | reference (earlier path) | 100 | 0 | 0 | {mse_ref:.8f} | 0 |")
        for label, m in (("earlier path", base.substeps),
                         ("recoat-free (now)", SMOOTH_SUBSTEPS)):
            tr = dense(printer(m), sc)
            err = jnp.abs(tr.temperature - ref.temperature)
            mse = float(jnp.mean((tr.y - tr.r) ** 2))
            lines.append(f"| {kind} | {label} | {m} | {float(err.max()):.2e} | "
                         f"{float(jnp.sqrt(jnp.mean(err ** 2))):.2e} | {mse:.8f} | "
                         f"{abs(mse - mse_ref) / mse_ref:.1e} |")
            print(lines[-1], flush=True)
    B = args.time_rollouts
    lines += ["", f"## The run program at B = {B} (second call, compiled)", "",
              "| path | sub-steps | wall s | CPU s | load | mse |", "|---|---|---|---|---|---|"]
    full = eqx.filter_jit(lambda p, c, k: engine.run_metrics(p, c, cl.make_scenario(
        "tracking", p, args.duration, k, n_rollouts=B), True))
    key = jax.random.key(0)
    for label, fn, m in (
            ("earlier (recoat term, 10 sub-steps)", lambda: full(base, ctrl, key),
             base.substeps),
            ("now (recoat=False)", lambda: engine.scenario_metrics(
                "tracking", base, ctrl, args.duration, key, B), SMOOTH_SUBSTEPS)):
        load_now = load()
        out, wall, cpu = timed(fn)
        lines.append(f"| {label} | {m} | {wall:.2f} | {cpu:.2f} | {load_now} | "
                     f"{float(out[0]['mse']):.8f} |")
        print(lines[-1], flush=True)
    finish(lines, load0, args.out)


if __name__ == "__main__":
    sys.exit(main())
