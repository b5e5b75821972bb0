"""W2 benchmark: closed-loop rollouts per second, jthermo against NumPy and python-control.

Workload (W2 of /work/shared/bench/workloads.py): an N-zone linear bed (diagonal A,
grid-coupled B), diagonal discrete PI with clamping anti-windup, +4 °C reference step from
ambient, random cold-layer drops (state jumps of −2 °C); B rollouts × T steps; the figure of
merit is zone-steps per second = B·T·N / seconds. Each rollout returns its tracking cost
(mean of (r − y)²), and the three implementations must agree on it.

- jthermo: `closedloop.rollout_costs` (the cost accumulated inside one `lax.scan`, vmapped over
  rollouts, jitted once); the bed is a `StateSpace` whose measured signals are the state jumps
  (Bw = I), the PI a `DiagonalPI`. Also `closedloop.rollouts` (full trajectories kept) where
  memory allows.
- NumPy: `rollout_numpy` of the workload file, a loop over time vectorised over the batch.
- python-control: `input_output_response` on a discrete nonlinear I/O system (plant + PI with
  saturation and clamping) per rollout; slow, so it runs a few rollouts and its time is
  extrapolated linearly to B (stated in the table).

Cold = first call including compilation; warm = median of repeats. Memory: XLA's buffer
analysis of the compiled call (arguments + outputs + temporaries) for jthermo, tracemalloc peak
for NumPy. Configurations whose input arrays alone exceed `--max-gb` are skipped (stated).

    python benchmarks/closedloop.py            # N in {4,16,64}, B in {1,256,4096}, T = 3600
    python benchmarks/closedloop.py --quick    # N in {4,16}, B in {1,256}, T = 600 (_quick.md)
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jthermo.closedloop import ModelDisturbance, Scenario, rollout_costs, rollouts
from jthermo.control.pi import DiagonalPI
from jthermo.data import atomic_write_text
from jthermo.models import StateSpace

BENCH = Path(os.environ.get("JTHERMO_BENCH", "/work/shared/bench"))
HERE = Path(__file__).resolve().parent
TRACKING_ONLY = {"tracking": 1.0, "uniformity": 0.0, "effort": 0.0, "window": 0.0}


def load_workloads():
    sys.path.insert(0, str(BENCH))
    try:
        import workloads  # type: ignore
    finally:
        sys.path.pop(0)
    return workloads


def jax_problem(setup):
    p = setup["plant"]
    N, B, T = setup["N"], setup["B"], setup["T"]
    model = StateSpace(p["A"], p["B"], np.eye(N), Bw=np.eye(N), u0=np.zeros(N), w0=np.zeros(N),
                       y0=np.zeros(N))
    pi = DiagonalPI(setup["kp"], setup["kp"] / setup["ki"], setup["u_ff"], antiwindup="clamp")
    d = jnp.asarray(setup["d"])
    sc = Scenario(r=jnp.broadcast_to(jnp.asarray(setup["r"]), (B, T, N)),
                  d=ModelDisturbance(w=d, dy=jnp.zeros_like(d)), v=jnp.zeros_like(d),
                  y0=jnp.zeros((B, N)))
    x0s = jnp.zeros((B, N))
    return model, pi, sc, x0s


@eqx.filter_jit
def jax_costs(model, pi, sc, x0s):
    return rollout_costs(model, pi, sc, TRACKING_ONLY, x0s)


@eqx.filter_jit
def jax_traj_costs(model, pi, sc, x0s):
    tr = rollouts(model, pi, sc, x0s)
    return jnp.mean((tr.y - tr.r) ** 2, axis=(1, 2))


def timed(f, repeats):
    t0 = time.perf_counter()
    out = jax.block_until_ready(f())
    cold = time.perf_counter() - t0
    warm = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f())
        warm.append(time.perf_counter() - t0)
    return out, cold, statistics.median(warm) if warm else cold


def xla_bytes(fn, *args):
    try:
        m = jax.jit(lambda *a: fn(*a)).lower(*args).compile().memory_analysis()
        return int(m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes)
    except Exception:   # memory analysis is not available on every backend
        return -1


def python_control_costs(setup, n_rollouts):
    import control as ct
    p = setup["plant"]
    a, Bm, r, uff = p["a"], p["B"], setup["r"], setup["u_ff"]
    kp, ki = setup["kp"], setup["ki"]
    N, T = setup["N"], setup["T"]

    def upd(t, z, d, params):
        x, s = z[:N], z[N:]
        e = r - x
        s_try = s + e
        v = uff + kp * e + ki * s_try
        u = np.clip(v, 0.0, 1.0)
        wind = ((v > 1.0) & (e > 0.0)) | ((v < 0.0) & (e < 0.0))
        return np.concatenate([a * x + Bm @ u + d, np.where(wind, s, s_try)])

    sys_ = ct.nlsys(upd, lambda t, z, d, params: z[:N], inputs=N, outputs=N, states=2 * N, dt=1)
    costs = []
    t0 = time.perf_counter()
    for b in range(n_rollouts):
        res = ct.input_output_response(sys_, np.arange(T), setup["d"][b].T, np.zeros(2 * N))
        y = res.outputs.T
        costs.append(np.mean((r - y) ** 2))
    return np.array(costs), (time.perf_counter() - t0) / n_rollouts


def run(Ns, Bs, T, repeats, pc_rollouts, max_gb, traj_max_gb, scaling):
    wl = load_workloads()
    rows, checks = [], []
    for N in Ns:
        for B in Bs:
            gb = 3 * B * T * N * 8 / 1e9         # d, r, v as float64 arrays
            if gb > max_gb:
                rows.append({"N": N, "B": B, "skip": f"inputs {gb:.1f} GB > {max_gb:g} GB"})
                continue
            setup = wl.closed_loop_setup(N, T, B, seed=0)
            zs = B * T * N
            args = jax_problem(setup)
            J, jc, jw = timed(lambda: jax_costs(*args), repeats)
            jmem = xla_bytes(jax_costs, *args)
            tracemalloc.start()
            t0 = time.perf_counter()
            Jn = wl.rollout_numpy(setup)
            nw = time.perf_counter() - t0
            npeak = tracemalloc.get_traced_memory()[1] + setup["d"].nbytes
            tracemalloc.stop()
            if repeats:
                more = []
                for _ in range(min(repeats, 2)):
                    t0 = time.perf_counter()
                    wl.rollout_numpy(setup)
                    more.append(time.perf_counter() - t0)
                nw = statistics.median([nw] + more)
            err = float(np.max(np.abs(np.asarray(J) - Jn)))
            checks.append(err)
            row = {"N": N, "B": B, "jax_cold": jc, "jax_warm": jw, "numpy": nw, "zs": zs,
                   "jax_mem": jmem, "np_mem": npeak, "err": err}
            if 3 * B * T * N * 8 / 1e9 * 2.5 <= traj_max_gb:
                _, tc, tw = timed(lambda: jax_traj_costs(*args), repeats)
                row["traj_warm"] = tw
                row["traj_cold"] = tc
                row["traj_mem"] = xla_bytes(jax_traj_costs, *args)
            if N <= 16 and B in (1, 256) and pc_rollouts:
                nb = min(pc_rollouts, B)
                Jp, per = python_control_costs(setup, nb)
                row["pc_per_rollout"] = per
                row["pc_rollouts"] = nb
                row["pc_err"] = float(np.max(np.abs(Jp - Jn[:nb])))
            rows.append(row)
            print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in row.items()},
                  flush=True)
    scale = []
    if scaling:
        N = 16
        for B, TT in ((64, T), (256, T // 4), (256, T // 2), (256, T), (1024, T)):
            setup = wl.closed_loop_setup(N, TT, B, seed=0)
            args = jax_problem(setup)
            _, _, w = timed(lambda: jax_costs(*args), max(repeats, 1))
            scale.append({"B": B, "T": TT, "warm": w, "zs_per_s": B * TT * N / w})
            print(scale[-1], flush=True)
    return rows, scale, checks


def fmt_rate(x):
    return f"{x:.2e}"


def report(rows, scale, T, args):
    dev = jax.devices()[0]
    lines = ["# Closed-loop rollouts (W2): jthermo vs NumPy vs python-control", "",
             f"Command: `python benchmarks/closedloop.py{' --quick' if args.quick else ''}`. "
             f"Machine: {platform.machine()}, {os.cpu_count()} CPU cores, JAX {jax.__version__} "
             f"on {dev.platform}; float64; T = {T} steps. Zone-steps/s = B·T·N / seconds; "
             "warm = median of repeats, cold = first call with compilation. Each implementation's "
             "per-rollout cost agrees with NumPy's to the `max |ΔJ|` shown.", "",
             "| N | B | jthermo warm s | zone-steps/s | cold s | NumPy s | zone-steps/s | ×NumPy "
             "| python-control s (extrapolated) | ×python-control | jthermo trajectories kept: warm s (memory) "
             "| memory jthermo / NumPy MB | max abs ΔJ |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "skip" in r:
            lines.append(f"| {r['N']} | {r['B']} | skipped: {r['skip']} |||||||||||")
            continue
        zs = r["zs"]
        pc = r.get("pc_per_rollout")
        pc_s = pc * r["B"] if pc else None
        pc_txt = (f"{pc_s:.3g} ({r['pc_rollouts']} run{'s' if r['pc_rollouts'] > 1 else ''} × "
                  f"{r['B'] / r['pc_rollouts']:g})") if pc else "—"
        pc_ratio = f"{pc_s / r['jax_warm']:.0f}" if pc else "—"
        traj = (f"{r['traj_warm']:.3g} ({r['traj_mem'] / 1e6:.0f} MB)" if "traj_warm" in r
                else "—")
        mem = f"{r['jax_mem'] / 1e6:.0f} / {r['np_mem'] / 1e6:.0f}" if r["jax_mem"] >= 0 else \
            f"— / {r['np_mem'] / 1e6:.0f}"
        lines.append(
            f"| {r['N']} | {r['B']} | {r['jax_warm']:.3g} | {fmt_rate(zs / r['jax_warm'])} | "
            f"{r['jax_cold']:.3g} | {r['numpy']:.3g} | {fmt_rate(zs / r['numpy'])} | "
            f"{r['numpy'] / r['jax_warm']:.1f} | {pc_txt} | {pc_ratio} | {traj} | {mem} | "
            f"{max(r['err'], r.get('pc_err', 0.0)):.1e} |")
    if scale:
        lines += ["", "Scaling (N = 16, warm): seconds should grow linearly in B and T.", "",
                  "| B | T | seconds | zone-steps/s |", "|---|---|---|---|"]
        for s in scale:
            lines.append(f"| {s['B']} | {s['T']} | {s['warm']:.3g} | {fmt_rate(s['zs_per_s'])} |")
    lines += ["", "python-control runs a few rollouts per configuration and its time is "
              "multiplied by B/(rollouts run) — an extrapolation, not a measurement at B. "
              "Skipped rows need more memory than `--max-gb` for the dense disturbance, set-point "
              "and noise arrays (B·T·N float64 each) on this machine.", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small grid for a smoke test")
    ap.add_argument("--max-gb", type=float, default=3.0, help="skip configurations above this")
    ap.add_argument("--out", default=None,
                    help="default benchmarks/results/closedloop.md (closedloop_quick.md with --quick)")
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = str(HERE / "results" / ("closedloop_quick.md" if args.quick else "closedloop.md"))
    if args.quick:
        Ns, Bs, T, repeats, pcr, scaling = (4, 16), (1, 256), 600, 2, 2, False
    else:
        Ns, Bs, T, repeats, pcr, scaling = (4, 16, 64), (1, 256, 4096), 3600, 2, 2, True
    rows, scale, checks = run(Ns, Bs, T, repeats, pcr, args.max_gb, traj_max_gb=2.0,
                              scaling=scaling)
    text = report(rows, scale, T, args)
    atomic_write_text(args.out, text)
    print(text)
    if checks and max(checks) > 1e-8:
        print(f"WARNING: jthermo and NumPy costs differ by {max(checks):.2e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
