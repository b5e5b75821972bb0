"""What the measurement noise of `jthermo simulate` costs, and what cheaper draws of the same
distribution cost. `Printer.sample_noise` (every printer scenario of
`make_scenario`, and `generate`) keeps its three float64 draws; since 2026-11-25 `closedloop.run`
on the printer (`jthermo simulate`) draws its noise inside the scan with `Printer.noise_stream`
(last row), which changed its random stream (mse 0.08304 -> the value in
benchmarks/results/latency.md) but not the distribution.

The noise of one rollout (`Printer.sample_noise` with the scenario's white 0.05 °C and the
`sensor_noise` effect) is three standard-normal draws: the scenario's white part, the
effect's white part and the AR(1) innovations. Options timed over B rollouts of T samples:

- `as is`: three float64 draws, the AR(1) filter as a `lax.scan`;
- `fused white`: the two white parts as one draw of std $\\sqrt{s_1^2 + s_2^2}$ (the same
  distribution), two float64 draws;
- `fused, float32 draws`: the same two draws made in float32 and cast (24-bit normals, far
  finer than the 0.05 °C noise);
- `in-scan stream`: `Printer.noise_stream(key, 0.05).sample(T)`, what `run` draws one sample
  at a time inside its scan: one float32 normal vector per sample from `fold_in(key, k)`,
  the white parts fused (`jthermo.printer.noise`).

Threefry unrolled as in the command (`runtime.unroll_threefry`). Each row: the second call
(compiled), CPU seconds of the process beside the wall seconds and the 1-minute load, and the
per-channel std and lag-1 autocorrelation of the zone noise (the statistics the options keep).

    python benchmarks/simulate_noise_options.py
    python benchmarks/simulate_noise_options.py --rollouts 32 --duration 600 --out -
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from common import finish, load, timed

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=256)
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--out", default=str(HERE / "results" / "simulate_noise_options.md"))
    args = ap.parse_args()
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    from jthermo import runtime

    runtime.unroll_threefry()
    from jthermo import closedloop as cl
    from jthermo.printer import make_printer

    pr = make_printer(args.zones, cl.REALISTIC_EFFECTS, powder="PA12", seed=0)
    T, ny, n = round(args.duration / pr.ts), pr.n_outputs, pr.zones
    p = pr.effects["sensor_noise"]
    white = 0.05

    def ar1(e):
        a, g = p["pole"], p["coloured_std_C"] * jnp.sqrt(1.0 - p["pole"] ** 2)
        c0 = p["coloured_std_C"] * e[0]
        _, col = jax.lax.scan(lambda c, ek: (a * c + g * ek, a * c + g * ek), c0, e[1:])
        return jnp.concatenate([c0[None], col], axis=0)

    def fused(key, dtype):
        k1, k2 = jax.random.split(key)
        s = jnp.sqrt(white ** 2 + p["white_std_C"] ** 2)
        v = s * jax.random.normal(k1, (T, ny), dtype).astype(jnp.float64)
        return v.at[:, :n].add(ar1(jax.random.normal(k2, (T, n), dtype).astype(jnp.float64)))

    options = {"as is (3 float64 draws)": lambda k: pr.sample_noise(k, T, white),
               "fused white (2 float64 draws)": lambda k: fused(k, jnp.float64),
               "fused, float32 draws (2)": lambda k: fused(k, jnp.float32),
               "in-scan stream (`Printer.noise_stream`, run's since 2026-11-25)":
                   lambda k: pr.noise_stream(k, white).sample(T)}
    load0 = load()
    lines = [f"# Measurement-noise draws: N = {args.zones}, B = {args.rollouts}, T = {T}", "",
             (f"`python benchmarks/simulate_noise_options.py --zones {args.zones} --rollouts "
              f"{args.rollouts} --duration {args.duration:g}`; second call, compiled; std and "
              "lag-1 autocorrelation: means over the zone channels (expected std "
              f"{float(jnp.sqrt(white ** 2 + p['white_std_C'] ** 2 + p['coloured_std_C'] ** 2)):.4f}"
              " °C)."), "",
             "| draws | wall s | CPU s | load | zone noise std °C | lag-1 autocorrelation |",
             "|---|---|---|---|---|---|"]
    keys = jax.random.split(jax.random.key(0), args.rollouts)
    for label, fn in options.items():
        f = jax.jit(jax.vmap(fn))
        load_now = load()
        v, wall, cpu = timed(lambda f=f: f(keys))
        z = v[:, :, :n]
        r1 = jnp.mean(z[:, 1:] * z[:, :-1]) / jnp.mean(z ** 2)
        lines.append(f"| {label} | {wall:.2f} | {cpu:.2f} | {load_now} | "
                     f"{float(jnp.std(z)):.4f} | {float(r1):.4f} |")
        print(lines[-1], flush=True)
    finish(lines, load0, args.out)


if __name__ == "__main__":
    sys.exit(main())
