"""W3 benchmark: seconds per gradient of the mean closed-loop cost with respect to the PI gains.

Workload (W2/W3 of ../shared/bench/workloads.py): a 16-zone linear bed, diagonal discrete
PI with clamping anti-windup, +4 °C reference step and random cold-layer drops, B = 256
rollouts × T = 3600 steps. jthermo computes the gradient with respect to the 2N gains
(`kp`, `ti` of `DiagonalPI`) by `jax.grad` through `closedloop.rollouts` (one scan, vmapped);
the baseline is finite differences with the NumPy batch simulator of the same workload
(`rollout_numpy`), forward differences (2N + 1 batch simulations, the cheapest FD gradient),
measured in the same run. Cold = first call including compilation; warm = median of repeats.

    python benchmarks/tuning.py            # full size, writes benchmarks/results/tuning.md
    python benchmarks/tuning.py --quick    # small, for a smoke test
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jthermo.closedloop import ModelDisturbance, Scenario, rollouts
from jthermo.control.pi import DiagonalPI
from jthermo.data import atomic_write_text
from jthermo.models import StateSpace

BENCH = Path(os.environ.get("JTHERMO_BENCH", Path(__file__).resolve().parents[1].parent / "shared" / "bench"))
HERE = Path(__file__).resolve().parent


def load_workloads():
    sys.path.insert(0, str(BENCH))
    try:
        import workloads  # type: ignore
    finally:
        sys.path.pop(0)
    return workloads


def jax_problem(setup):
    """The W2 workload in jthermo terms: the bed as a StateSpace whose measured signals `w` are
    the state jumps (Bw = I), the PI as `DiagonalPI`, the rollouts as a batched Scenario."""
    p = setup["plant"]
    N, B, T = setup["N"], setup["B"], setup["T"]
    model = StateSpace(p["A"], p["B"], np.eye(N), Bw=np.eye(N), u0=np.zeros(N), w0=np.zeros(N),
                       y0=np.zeros(N))
    d = jnp.asarray(setup["d"])
    sc = Scenario(r=jnp.broadcast_to(jnp.asarray(setup["r"]), (B, T, N)),
                  d=ModelDisturbance(w=d, dy=jnp.zeros_like(d)), v=jnp.zeros_like(d),
                  y0=jnp.zeros((B, N)), kind="w2", ts=1.0)
    ctrl = DiagonalPI(setup["kp"], setup["kp"] / setup["ki"], setup["u_ff"], ts=1.0)
    x0s = jnp.zeros((B, N))

    @eqx.filter_jit
    def value_and_grad(ctrl):
        def mean_cost(c):
            traj = rollouts(model, c, sc, x0s)
            return jnp.mean((traj.r - traj.y) ** 2)
        return eqx.filter_value_and_grad(mean_cost)(ctrl)

    return ctrl, value_and_grad


def fd_gradient(W, setup, kp, ti, rel=1e-6):
    """Forward differences of the mean NumPy cost with respect to (kp, ti)."""
    def J(kp_, ti_):
        return float(np.mean(W.rollout_numpy(setup, kp_, kp_ / ti_)))
    base = J(kp, ti)
    g = np.zeros(2 * kp.size)
    for i in range(kp.size):
        h = rel * max(1.0, abs(kp[i]))
        k2 = kp.copy(); k2[i] += h
        g[i] = (J(k2, ti) - base) / h
    for i in range(ti.size):
        h = rel * max(1.0, abs(ti[i]))
        t2 = ti.copy(); t2[i] += h
        g[kp.size + i] = (J(kp, t2) - base) / h
    return base, g


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (smoke test)")
    ap.add_argument("--zones", type=int, default=16)
    ap.add_argument("--rollouts", type=int, default=None)
    ap.add_argument("--steps", type=int, default=None, help="time steps per rollout")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(HERE / "results" / "tuning.md"))
    a = ap.parse_args(argv)
    B = a.rollouts or (32 if a.quick else 256)
    T = a.steps or (600 if a.quick else 3600)
    N = a.zones
    W = load_workloads()
    setup = W.closed_loop_setup(N, T, B, 0)
    ctrl, vg = jax_problem(setup)

    t = time.perf_counter()
    val, grads = vg(ctrl)
    jax.block_until_ready(grads)
    cold = time.perf_counter() - t
    warm = []
    for _ in range(a.repeats):
        t = time.perf_counter()
        jax.block_until_ready(vg(ctrl))
        warm.append(time.perf_counter() - t)
    warm_s = statistics.median(warm)
    g_jax = np.concatenate([np.asarray(grads.kp), np.asarray(grads.ti)])

    t = time.perf_counter()
    base, g_fd = fd_gradient(W, setup, np.asarray(setup["kp"], float),
                             np.asarray(setup["kp"] / setup["ki"], float))
    fd_s = time.perf_counter() - t
    t = time.perf_counter()
    W.rollout_numpy(setup)
    one_np = time.perf_counter() - t

    cost_err = abs(float(val) - base) / abs(base)
    g_err = float(np.max(np.abs(g_jax - g_fd)) / np.max(np.abs(g_fd)))
    dev = jax.devices()[0]
    lines = [
        "# W3: gradient of the mean closed-loop cost (jthermo `jax.grad` vs NumPy finite differences)",
        "",
        (f"Command: `python benchmarks/tuning.py{' --quick' if a.quick else ''}`. "
         f"N = {N} zones, B = {B} rollouts, T = {T} steps, 2N = {2 * N} gains (kp, Ti), float64."),
        (f"Machine: {platform.machine()} {os.cpu_count()} CPU cores, JAX device `{dev.platform}` "
         f"({dev.device_kind})."),
        "",
        "| method | seconds per gradient | ratio vs FD |",
        "|---|---|---|",
        f"| jthermo `jax.grad`, cold (with compilation) | {cold:.3f} | {fd_s / cold:.1f}× |",
        f"| jthermo `jax.grad`, warm (median of {a.repeats}) | {warm_s:.3f} | {fd_s / warm_s:.1f}× |",
        f"| NumPy batch simulator, forward differences ({2 * N + 1} runs) | {fd_s:.3f} | 1× |",
        "",
        (f"One NumPy batch simulation: {one_np:.3f} s. Cost agreement JAX vs NumPy: relative "
         f"{cost_err:.1e}; gradient agreement (max abs difference / max |FD|): {g_err:.1e} "
         "(forward differences carry O(h) error and straddle the anti-windup switching; the "
         "gradient itself is checked against central differences in tests/test_tune.py and "
         "tests/control/test_gradients.py)."),
        "",
        "Goal of the issue: warm ratio ≥ 100×. "
        + ("Met." if fd_s / warm_s >= 100 else "Not met on this machine."),
        "",
    ]
    text = "\n".join(lines)
    print(text)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(a.out, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
