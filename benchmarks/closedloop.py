"""W2 benchmark: closed-loop rollouts per second, jthermo against NumPy and python-control.

Workload (W2 of ../shared/bench/workloads.py): an N-zone linear bed (diagonal A,
grid-coupled B), diagonal discrete PI with clamping anti-windup, +4 °C reference step from
ambient, random cold-layer drops (state jumps of −2 °C); B rollouts × T steps; the figure of
merit is zone-steps per second = B·T·N / seconds. Each rollout returns its tracking cost
(mean of (r − y)²), and the three implementations must agree on it.

- jthermo, lean: `closedloop.rollout_costs` on a `CompactScenario` (the cost accumulated inside
  one `lax.scan`, vmapped over rollouts, jitted once; the drops as sparse events scattered into
  the measured signals inside the scan, so no (B, T, N) array exists); the bed is a `StateSpace`
  whose measured signals are the state jumps (Bw = I), the PI a `DiagonalPI`. float64 and float32.
- jthermo, dense: the same costs on the equivalent dense `Scenario`, and `closedloop.rollouts`
  (the generic path, full trajectories kept) where memory allows.
- NumPy: `rollout_numpy` of the workload file, a loop over time vectorised over the batch.
- python-control: `input_output_response` on a discrete nonlinear I/O system (plant + PI with
  saturation and clamping) per rollout; slow, so it runs a few rollouts and its time is
  extrapolated linearly to B (stated in the table).

Cold = first call including compilation; warm = median of repeats. Memory: XLA's buffer
analysis of the compiled call (arguments + outputs + temporaries) for jthermo, tracemalloc peak
for NumPy. NumPy and the dense paths are skipped where one dense (B, T, N) array exceeds
`--max-gb` (stated).

    python benchmarks/closedloop.py            # N in {4,16,64}, B in {1,256,4096}, T = 3600
    python benchmarks/closedloop.py --quick    # N in {4,16}, B in {1,256}, T = 600
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

from jthermo.closedloop import (
    CompactScenario,
    Events,
    ModelDisturbance,
    Scenario,
    rollout_costs,
    rollouts,
)
from jthermo.control.pi import DiagonalPI
from jthermo.data import atomic_write_text
from jthermo.models import StateSpace

BENCH = Path(os.environ.get("JTHERMO_BENCH", Path(__file__).resolve().parents[1].parent / "shared" / "bench"))
HERE = Path(__file__).resolve().parent
TRACKING_ONLY = {"tracking": 1.0, "uniformity": 0.0, "effort": 0.0, "window": 0.0}


def load_workloads():
    sys.path.insert(0, str(BENCH))
    try:
        import workloads  # type: ignore
    finally:
        sys.path.pop(0)
    return workloads


def w2_events(wl, N, T, B, seed=0):
    """The W2 cold-layer drops as sparse events (time, zone, size), drawn exactly as
    `workloads.make_disturbances` draws them, without the dense (B, T, N) array."""
    n_events = N
    rng = wl._rng(seed, N, T, B, 3)
    tt = rng.integers(T // 6, T - 1, size=B * n_events).reshape(B, n_events)
    zz = rng.integers(0, N, size=B * n_events).reshape(B, n_events)
    return tt, zz, np.full((B, n_events), -wl.DROP)


def jax_problem(wl, N, T, B, dtype=np.float64):
    """W2 as a fitted-model plant: Bw = I (the state jumps enter as measured signals), the PI,
    the lean `CompactScenario` (events, constant set point, no noise) and x0 = 0."""
    p = wl.make_plant(N, 0)
    def f(a):
        return jnp.asarray(a, dtype)

    model = StateSpace(f(p["A"]), f(p["B"]), f(np.eye(N)), Bw=f(np.eye(N)), u0=f(np.zeros(N)),
                       w0=f(np.zeros(N)), y0=f(np.zeros(N)))
    kp, ki = np.full(N, wl.KP0), np.full(N, wl.KI0)
    pi = DiagonalPI(f(kp), f(kp / ki), f(wl.U_FF), antiwindup="clamp")
    tt, zz, size = w2_events(wl, N, T, B)
    r = f(np.full((B, N), wl.R_STEP))
    sc = CompactScenario(r0=r, r1=r, t_step=jnp.zeros(B, jnp.int32), w=f(np.zeros((B, N))),
                         events=Events(jnp.asarray(tt, jnp.int32), jnp.asarray(zz, jnp.int32), f(size)),
                         y0=f(np.zeros((B, N))), n_samples=T)
    return model, pi, sc, f(np.zeros((B, N)))


def dense_scenario(setup):
    """The same rollouts as a dense `Scenario` ((B, T, N) arrays for r, w, dy, v)."""
    N, B, T = setup["N"], setup["B"], setup["T"]
    d = jnp.asarray(setup["d"])
    return Scenario(r=jnp.broadcast_to(jnp.asarray(setup["r"]), (B, T, N)),
                    d=ModelDisturbance(w=d, dy=jnp.zeros_like(d)), v=jnp.zeros_like(d),
                    y0=jnp.zeros((B, N)))


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
            zs = B * T * N
            args = jax_problem(wl, N, T, B)
            J, jc, jw = timed(lambda: jax_costs(*args), repeats)
            row = {"N": N, "B": B, "jax_cold": jc, "jax_warm": jw, "zs": zs,
                   "jax_mem": xla_bytes(jax_costs, *args)}
            args32 = jax_problem(wl, N, T, B, np.float32)
            J32, _, row["f32_warm"] = timed(lambda: jax_costs(*args32), repeats)
            gb = B * T * N * 8 / 1e9          # one dense (B, T, N) float64 array
            if gb > max_gb:
                row["skip"] = f"dense inputs {gb:.1f} GB > {max_gb:g} GB"
                rows.append(row)
                print(row, flush=True)
                continue
            setup = wl.closed_loop_setup(N, T, B, seed=0)
            tracemalloc.start()
            t0 = time.perf_counter()
            Jn = wl.rollout_numpy(setup)
            nw = time.perf_counter() - t0
            npeak = tracemalloc.get_traced_memory()[1] + setup["d"].nbytes
            tracemalloc.stop()
            # interleave NumPy and jthermo repeats: ratios from the same moments of a busy machine
            ratios, more = [nw / jw], []
            for _ in range(min(repeats, 2)):
                t0 = time.perf_counter()
                wl.rollout_numpy(setup)
                more.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                jax.block_until_ready(jax_costs(*args))
                ratios.append(more[-1] / (time.perf_counter() - t0))
            nw = statistics.median([nw] + more)
            err = float(np.max(np.abs(np.asarray(J) - Jn)))
            checks.append(err)
            row.update({"numpy": nw, "np_mem": npeak, "err": err, "ratio": statistics.median(ratios),
                        "err32": float(np.max(np.abs(np.asarray(J32) - Jn) / np.abs(Jn)))})
            if 4 * gb * 2.5 <= traj_max_gb:
                sc = dense_scenario(setup)
                dargs = (args[0], args[1], sc, args[3])
                Jd, _, row["dense_warm"] = timed(lambda: jax_costs(*dargs), repeats)
                row["dense_mem"] = xla_bytes(jax_costs, *dargs)
                _, _, tw = timed(lambda: jax_traj_costs(*dargs), repeats)
                row["traj_warm"] = tw
                row["traj_mem"] = xla_bytes(jax_traj_costs, *dargs)
                checks.append(float(np.max(np.abs(np.asarray(Jd) - Jn))))
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
        for B, TT in ((64, T), (256, T // 4), (256, T // 2), (256, T), (1024, T), (4096, T)):
            args = jax_problem(wl, N, TT, B)
            _, _, w = timed(lambda: jax_costs(*args), max(repeats, 1))
            scale.append({"B": B, "T": TT, "warm": w, "zs_per_s": B * TT * N / w})
            print(scale[-1], flush=True)
    return rows, scale, checks


def fmt_rate(x):
    return f"{x:.2e}"


def _mb(x):
    return f"{x / 1e6:.3g}" if x >= 0 else "—"


def report(rows, scale, T, args):
    dev = jax.devices()[0]
    lines = ["# Closed-loop rollouts (W2): jthermo vs NumPy vs python-control", "",
             f"Command: `python benchmarks/closedloop.py{' --quick' if args.quick else ''}`. "
             f"Machine: {platform.machine()}, {os.cpu_count()} CPU cores (shared with other jobs "
             f"while measured: compare ratios, not seconds), JAX {jax.__version__} on "
             f"{dev.platform}; T = {T} steps. Zone-steps/s = B·T·N / seconds; warm = median of "
             "repeats, cold = first call with compilation. ×NumPy = median of the ratios of "
             "interleaved NumPy / jthermo repeats.", "",
             "- **lean**: `rollout_costs` on a `CompactScenario` (constant set point, the cold-layer "
             "drops as sparse events, noise none): no (B, T, N) array anywhere, float64 "
             "(reference) and float32.",
             "- **dense**: `rollout_costs` on the equivalent dense `Scenario` (B·T·N arrays for r, "
             "w, dy, v); **trajectories**: `rollouts` (the generic path, every signal kept) and "
             "the cost from it.", "",
             "| N | B | lean f64 warm s | zone-steps/s | cold s | lean f32 warm s | NumPy s | ×NumPy "
             "| python-control s (extrapolated) | ×python-control | dense cost warm s | "
             "trajectories warm s | memory MB lean / dense / trajectories / NumPy | max abs ΔJ (f64) "
             "| max rel ΔJ (f32) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        zs = r["zs"]
        head = (f"| {r['N']} | {r['B']} | {r['jax_warm']:.3g} | {fmt_rate(zs / r['jax_warm'])} | "
                f"{r['jax_cold']:.3g} | {r['f32_warm']:.3g} | ")
        if "skip" in r:
            lines.append(head + f"skipped: {r['skip']} | | | | | | {_mb(r['jax_mem'])} / — / — / — | | |")
            continue
        pc = r.get("pc_per_rollout")
        pc_s = pc * r["B"] if pc else None
        pc_txt = (f"{pc_s:.3g} ({r['pc_rollouts']} run{'s' if r['pc_rollouts'] > 1 else ''} × "
                  f"{r['B'] / r['pc_rollouts']:g})") if pc else "—"
        pc_ratio = f"{pc_s / r['jax_warm']:.0f}" if pc else "—"
        dense = f"{r['dense_warm']:.3g}" if "dense_warm" in r else "—"
        traj = f"{r['traj_warm']:.3g}" if "traj_warm" in r else "—"
        mem = (f"{_mb(r['jax_mem'])} / {_mb(r.get('dense_mem', -1))} / "
               f"{_mb(r.get('traj_mem', -1))} / {_mb(r['np_mem'])}")
        lines.append(head +
            f"{r['numpy']:.3g} | {r['ratio']:.1f} | {pc_txt} | {pc_ratio} | {dense} | {traj} | "
            f"{mem} | {max(r['err'], r.get('pc_err', 0.0)):.1e} | {r['err32']:.1e} |")
    if scale:
        lines += ["", "Scaling (lean, float64, N = 16, warm): seconds should grow linearly in B and T.", "",
                  "| B | T | seconds | zone-steps/s |", "|---|---|---|---|"]
        for s in scale:
            lines.append(f"| {s['B']} | {s['T']} | {s['warm']:.3g} | {fmt_rate(s['zs_per_s'])} |")
    lines += ["", "python-control runs a few rollouts per configuration and its time is "
              "multiplied by B/(rollouts run) — an extrapolation, not a measurement at B. "
              "NumPy and the dense paths are skipped where one dense (B, T, N) float64 array "
              "exceeds `--max-gb`. Memory: XLA's buffer analysis (arguments + outputs + "
              "temporaries) for jthermo, tracemalloc peak plus the disturbance array for NumPy. "
              "XLA CPU threading is left at its defaults (the library sets no XLA flags).", ""]
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small grid for a smoke test")
    ap.add_argument("--max-gb", type=float, default=3.0, help="skip configurations above this")
    ap.add_argument("--out", default=None,
                    help="default benchmarks/results/closedloop.md")
    args = ap.parse_args(argv)
    if args.out is None:
        args.out = str(HERE / "results" / "closedloop.md")
    if args.quick:
        Ns, Bs, T, repeats, pcr, scaling = (4, 16), (1, 256), 600, 2, 2, False
    else:
        Ns, Bs, T, repeats, pcr, scaling = (4, 16, 64), (1, 256, 4096), 3600, 2, 2, True
    rows, scale, checks = run(Ns, Bs, T, repeats, pcr, args.max_gb, traj_max_gb=3.0,
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
