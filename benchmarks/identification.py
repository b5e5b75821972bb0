"""W1 identification benchmark: jthermo against SIPPY and jax-sysid on the same data, same run.

Workload W1 of `../shared/bench/README.md` (imported from `../shared/bench/workloads.py` when
present, otherwise re-created below): an N-zone linear bed, band-limited PRBS inputs, coloured
measurement noise, T = 6000 samples for estimation and for validation (separate seeds). For each
family (ARX, ARMAX, OE, BJ, SS) and N in {4, 16}: fitting time, cold (first call in the process,
JAX compilation included) and warm (second call, same shapes), and the validation simulation fit
% (models simulated from rest, x = 0 at u = 0, as the workload's data start), next to the oracle
fit (noise-free truth vs measured). Peers run in a child process each (with a time limit), so a
slow or crashing peer cannot stop the run; their time is measured inside the child around the
fit call only.

Usage:
    python benchmarks/identification.py [--quick] [--peers none|sippy|all] [--n 4 16]
        [--families arx armax oe bj ss] [--engines jax numpy] [--peer-timeout 900] [--json PATH]
    python benchmarks/identification.py --default-path --n 16 --families oe bj
        (the default path a user takes: `jthermo fit` with automatic orders, cold, from the
        shell, wall time and peak RSS, gap to the true model; `default_path`)

Writes a Markdown table to stdout and to `benchmarks/results/identification.md`.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import sys
import time
from pathlib import Path

# One BLAS thread for every tool (set before NumPy loads; the peers' child processes inherit
# it). On the shared 2-core machine OpenBLAS's spinning worker threads made small LAPACK calls
# 10-50x slower and their times erratic (SIPPY N4SID 65 s instead of 0.3 s), for every tool.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
from common import markdown_table_head  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED_BENCH = ROOT / ".." / "shared" / "bench" / "workloads.py"
RESULTS = ROOT / "benchmarks" / "results"
T = 6000
FAMILIES = ("arx", "armax", "oe", "bj", "n4sid", "ss")
#: orders matching the W1 plant (first order per zone, one-sample input delay)
JT_ORDERS = {"arx": (1, 1, 1), "armax": (1, 1, 1, 1), "oe": (1, 1, 1), "bj": (1, 1, 1, 1, 1)}
SIPPY_METHOD = {"arx": "ARX", "armax": "ARMAX", "oe": "OE", "bj": "BJ", "n4sid": "N4SID"}
#: W1 outputs are temperatures in °C above ambient and the record starts at ambient (the
#: workload's definition): the output level at rest is 0, which SIPPY, fitting the raw data,
#: assumes too. `--estimate-level` makes jthermo estimate it instead (its "rest" default).
REST_LEVEL = 0.0
#: the peers' own environment (`make bench-peers`): jax-sysid pins an older JAX than jthermo's
PEERS_PYTHON = ROOT / ".venv-peers" / "bin" / "python"


# ----------------------------------------------------------------------------- workload


def load_workloads():
    """The shared W1 definition, or a re-creation of it (same docstring contract)."""
    path = SHARED_BENCH.resolve()
    if path.exists():
        spec = importlib.util.spec_from_file_location("jthermo_bench_workloads", path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        return mod
    return _Workloads()


def w1_prbs(T: int, N: int, rng: np.random.Generator) -> np.ndarray:
    """W1 input: levels {0.3, 0.7}, random holds of 3..15 samples, independent per zone."""
    u = np.empty((T, N))
    for j in range(N):
        level, t = rng.integers(0, 2), 0
        while t < T:
            hold = int(rng.integers(3, 16))
            u[t:t + hold, j] = 0.7 if level else 0.3
            t, level = t + hold, 1 - level
    return u


class _Workloads:
    """Re-creation of W1 from the README/docstring of ../shared/bench/workloads.py."""

    SIGMA_W, NOISE_STD, NOISE_POLE = 0.02, 0.1, 0.7

    @staticmethod
    def _rng(*key):
        return np.random.default_rng(np.random.SeedSequence([int(k) for k in key]))

    def make_plant(self, N, seed=0):
        rng = self._rng(seed, N, 0)
        a, b = rng.uniform(0.92, 0.96, N), rng.uniform(0.15, 0.25, N)
        rows = max(1, int(np.floor(np.sqrt(N))))
        cols = int(np.ceil(N / rows))
        P = np.stack([np.arange(N) // cols, np.arange(N) % cols], 1).astype(float)
        d2 = ((P[:, None] - P[None]) ** 2).sum(-1)
        return {"A": np.diag(a), "B": b[:, None] * np.exp(-d2 / 0.8), "a": a, "b": b}

    def _sim(self, plant, u, w=None):
        x = np.zeros_like(u)
        Bu = u @ plant["B"].T + (0 if w is None else w)
        for k in range(len(u) - 1):
            x[k + 1] = plant["a"] * x[k] + Bu[k]
        return x

    def make_dataset(self, N, T, seed=0, split=1):
        plant = self.make_plant(N, seed)
        rng = self._rng(seed, N, T, split)
        u = w1_prbs(T, N, rng)
        w = self.SIGMA_W * rng.standard_normal((T, N))
        e = rng.standard_normal((T, N))
        g = self.NOISE_STD * np.sqrt(1 - self.NOISE_POLE ** 2)
        v = np.empty((T, N))
        v[0] = self.NOISE_STD * e[0]
        for k in range(1, T):
            v[k] = self.NOISE_POLE * v[k - 1] + g * e[k]
        x = self._sim(plant, u, w)
        return {"u": u, "y": x + v, "x": x, "y_clean": self._sim(plant, u), "plant": plant}

    def estimation_validation(self, N, T, seed=0):
        return self.make_dataset(N, T, seed, 1), self.make_dataset(N, T, seed, 2)

    @staticmethod
    def fit_percent(y, yhat):
        num = np.linalg.norm(y - yhat, axis=0)
        den = np.linalg.norm(y - y.mean(axis=0), axis=0)
        return float(np.mean(100.0 * (1.0 - num / den)))


# ----------------------------------------------------------------------------- jthermo


def simulate_from_rest(model, u: np.ndarray) -> np.ndarray:
    """Simulate a jthermo model from rest at u = 0 (the workload's ambient start)."""
    from jthermo.models.polynomial import Polynomial

    if isinstance(model, Polynomial):
        # direct filters: the common-denominator realisation of a 16-input row has degree 16
        # with clustered poles, which is numerically useless. Linearity: from rest at u = 0 is
        # y0 - G(1) u0 plus the zero-state response to u.
        import equinox as eqx
        import jax.numpy as jnp

        ny = model.n_outputs
        A1 = np.eye(ny) + np.asarray(model.a_matrices()).sum(axis=0)
        G1 = np.linalg.solve(A1, np.asarray(model.b).sum(-1) / (1.0 + np.asarray(model.f).sum(-1)))
        m0 = eqx.tree_at(lambda m: m.u0, model, jnp.zeros_like(model.u0))
        return np.asarray(m0.simulate(u)) - G1 @ np.asarray(model.u0)
    ss = model.to_statespace()
    A, B, u0 = (np.asarray(m) for m in (ss.A, ss.B, ss.u0))
    try:
        x0 = np.linalg.solve(np.eye(A.shape[0]) - A, B @ (0.0 - u0))
    except np.linalg.LinAlgError:
        x0 = np.zeros(A.shape[0])
    return np.asarray(ss.simulate(u, x0=x0))


#: families with a PEM engine choice (`fit_polynomial(engine=...)`)
ENGINE_FAMILIES = ("armax", "oe", "bj")


def jthermo_fit(family: str, data, N: int, seed: int = 0, engine: str = "auto"):
    from jthermo.identify.fit import fit

    eng = {"engine": engine} if family in ENGINE_FAMILIES else {}

    if family == "n4sid":   # subspace only (CVA weighting), no PEM
        from types import SimpleNamespace

        from jthermo.identify.subspace import n4sid
        # SIPPY's N4SID method: W1 = I, the oblique projection itself (`weighting="n4sid"`;
        # jthermo's default CVA scores 0.007-0.018 points lower on W1 N = 4,
        # `benchmarks/results/peers_fit_gap_n4.md`)
        return SimpleNamespace(model=n4sid(data, N, rest_level=REST_LEVEL, weighting="n4sid")[0],
                               converged=True)
    if family == "ss":
        # N4SID start + PEM of the simulation error (the workload's fit % is a simulation fit,
        # and jax-sysid fits the simulation error too); one start and few steps at N = 16,
        # where the dense LM Jacobian is (96000 x 544)
        return fit(data, "ss", (N,), seed=seed, n_starts=2 if N <= 4 else 1,
                   max_steps=30 if N <= 4 else 8, covariance=N <= 4, focus="simulation")
    if family in ("oe", "bj"):
        # SIPPY's MIMO OE/BJ structure: one denominator F per output, shared by its inputs
        return fit(data, family, JT_ORDERS[family], seed=seed, n_starts=4, common_f=True,
                   rest_level=REST_LEVEL, **eng, **({} if N <= 4 else {"screen_steps": 5}))
    # N = 16: at most 20 LM steps per output row, MATLAB pem's default MaxIterations, and 5
    # screening steps per start
    return fit(data, family, JT_ORDERS[family], seed=seed, n_starts=4, rest_level=REST_LEVEL,
               **eng, **({} if N <= 4 else {"max_steps": 20, "screen_steps": 5}))


def timed(fn):
    """`(fn(), wall s, CPU s)`: CPU = user + system time of this process, all its threads (XLA's
    compiler threads included); under a shared machine's load the wall time grows, CPU much less."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def jthermo_child(family: str, N: int, cache: str, warm: bool, engine: str = "auto") -> dict:
    """One fresh process with the persistent compilation cache at `cache` (what `jthermo fit`
    uses): the first fit call (`cold_*`, compilation or cache loads included; imports and data
    excluded), then a second call on the same data (`warm_*`), then the validation fit."""
    import jax

    jax.config.update("jax_enable_x64", True)
    from jthermo import runtime
    from jthermo.data import from_arrays
    from jthermo.identify.fit import fit  # noqa: F401 - imported before the clock starts

    runtime.enable_cache(cache)
    W = load_workloads()
    est, val = W.estimation_validation(N, T, 0)
    data = from_arrays(est["u"], est["y"])
    row = {"tool": jthermo_tool(engine), "family": family, "N": N}
    for key in ("cold", "warm")[:2 if warm else 1]:
        res, row[f"{key}_s"], row[f"{key}_cpu"] = timed(
            lambda: jax.block_until_ready(jthermo_fit(family, data, N, engine=engine)))
    row["fit"] = W.fit_percent(val["y"], simulate_from_rest(res.model, val["u"]))
    row["note"] = "" if res.converged else "not converged"
    if family in ENGINE_FAMILIES:
        row["engine_used"] = (res.extra or {}).get("engine")
    return row


def run_child(python: str, args: list[str], timeout: float) -> dict:
    """Run this script's `--child ...` in a fresh process (`nice -n 5`); its last JSON line."""
    import subprocess

    cmd = ["nice", "-n", "5", python, str(Path(__file__).resolve()), "--child", *args]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT,
                           check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout:.0f} s"}
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode != 0 or not lines:
        return {"error": (p.stderr.strip().splitlines() or [f"exit {p.returncode}"])[-1][:160]}
    return json.loads(lines[-1])


def jthermo_tool(engine: str) -> str:
    """The tool column of a jthermo row: `jthermo` (the default, `engine="auto"`), `jthermo jax`
    (compiled PEM), `jthermo numpy` (NumPy PEM)."""
    return "jthermo" if engine == "auto" else f"jthermo {engine}"


def run_jthermo(family: str, N: int, timeout: float, engine: str = "auto") -> dict:
    """Two fresh processes sharing one new cache directory: the first meets an empty cache
    (cold, then warm), the second the cache the first wrote (`cached_*`: a user's repeat call)."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="jthermo-bench-cache-") as cache:
        level = "zero" if REST_LEVEL == 0.0 else "estimated"
        row = {"tool": jthermo_tool(engine), "family": family, "N": N, **run_child(
            sys.executable, ["jthermo", family, str(N), cache, level, "warm", engine], timeout)}
        if "error" not in row:
            again = run_child(sys.executable, ["jthermo", family, str(N), cache, level, "cold",
                                               engine], timeout)
            row.update({"cached_s": again.get("cold_s"), "cached_cpu": again.get("cold_cpu")})
            if "error" in again:
                row["note"] = f"cached process: {again['error']}"
    row["load"] = os.getloadavg()[0]
    return row


# ----------------------------------------------------------------------------- peers


def _lfilter_sim(num, den, u: np.ndarray) -> np.ndarray:
    """Simulate a MIMO transfer-function matrix given as nested coefficient lists (z powers)."""
    from scipy.signal import lfilter

    ny, nu = len(num), len(num[0])
    y = np.zeros((u.shape[0], ny))
    for i in range(ny):
        for j in range(nu):
            b = np.atleast_1d(np.asarray(num[i][j], dtype=float)).ravel()
            a = np.atleast_1d(np.asarray(den[i][j], dtype=float)).ravel()
            if len(b) < len(a):
                b = np.concatenate([np.zeros(len(a) - len(b)), b])
            y[:, i] += lfilter(b, a, u[:, j])
    return y


def _sippy_fit(family: str, est: dict, N: int):
    from sippy_unipi import system_identification

    y, u = est["y"].T, est["u"].T
    kw = {"arx": {"ARX_orders": [1, 1, 0]}, "armax": {"ARMAX_orders": [1, 1, 1, 0]},
          "oe": {"OE_orders": [1, 1, 0]}, "bj": {"BJ_orders": [1, 1, 1, 1, 0]},
          "n4sid": {"SS_fixed_order": N}}[family]
    return system_identification(y, u, SIPPY_METHOD[family], **kw)


def _sippy_sim(model, family: str, u: np.ndarray) -> np.ndarray:
    if family == "n4sid":
        A, B, C, D = (np.asarray(m) for m in (model.A, model.B, model.C, model.D))
        x = np.zeros(A.shape[0])
        y = np.empty((u.shape[0], C.shape[0]))
        for k in range(u.shape[0]):
            y[k] = C @ x + D @ u[k]
            x = A @ x + B @ u[k]
        return y
    return _lfilter_sim(model.NUMERATOR, model.DENOMINATOR, u)


#: a peer fit taking more CPU s than this is called once (its warm time = its cold time: the
#: peers compile nothing, and SIPPY OE/BJ at N = 16 take minutes per call)
PEER_WARM_MAX_CPU = 60.0


def peer_child(tool: str, family: str, N: int) -> dict:
    """One fresh process of the peers' environment: fit (timed), fit again unless the first
    call took more than `PEER_WARM_MAX_CPU` (warm), simulate the validation record from rest.
    jax-sysid is configured as its documentation recommends (`peers.SYSID_CONFIGS['doc']`)."""
    W = load_workloads()
    est, val = W.estimation_validation(N, T, 0)
    row = {"tool": tool, "family": family, "N": N}
    if tool == "SIPPY":
        fit_once = (lambda: _sippy_fit(family, est, N))
    else:
        from peers import sysid_fit, sysid_sim_from_rest

        fit_once = (lambda: sysid_fit(est, N, "doc"))
    model, row["cold_s"], row["cold_cpu"] = timed(fit_once)
    if row["cold_cpu"] <= PEER_WARM_MAX_CPU:
        model, row["warm_s"], row["warm_cpu"] = timed(fit_once)
    else:
        row.update(warm_s=row["cold_s"], warm_cpu=row["cold_cpu"], note="one call")
    if tool == "SIPPY":
        yhat = _sippy_sim(model, family, val["u"])
    else:
        yhat = sysid_sim_from_rest(*model, val["u"])
    fitp = W.fit_percent(val["y"], yhat)
    row["fit"] = fitp if np.isfinite(fitp) else float("-inf")
    if not np.isfinite(fitp) or np.max(np.abs(yhat)) > 1e6:
        row["note"] = "unstable simulation"
    return row


def run_peer(python: str, tool: str, family: str, N: int, timeout: float) -> dict:
    row = {"tool": tool, "family": family, "N": N,
           **run_child(python, ["peer", tool, family, str(N)], timeout)}
    row["load"] = os.getloadavg()[0]
    return row


# ----------------------------------------------------------------------------- report


def _fmt(x, nd=2):
    if x is None or (isinstance(x, float) and np.isnan(x)):
        return "—"
    if isinstance(x, float) and np.isinf(x):
        return "−inf"
    return f"{x:.{nd}f}" if abs(x) < 1000 else f"{x:.0f}"


def _ratio(num, den) -> str:
    return "—" if num is None or not den else f"{num / den:.1f}×"


def _speedups(r: dict, refs: list[dict], unit: str) -> str:
    """Peer time / jthermo time: cold (empty cache) / cold with the cache warm / warm, against
    each jthermo row of the family and N (one line per PEM engine)."""
    if r["tool"].startswith("jthermo") or not refs or "cold_" + unit not in r:
        return "—"
    cells = [" / ".join(_ratio(r[f"{p}_{unit}"], ref.get(f"{j}_{unit}")) for p, j in
                        (("cold", "cold"), ("cold", "cached"), ("warm", "warm"))) for ref in refs]
    if len(refs) == 1:
        return cells[0]
    return "<br>".join(f"{ref['tool']}: {c}" for ref, c in zip(refs, cells))


def markdown(rows: list[dict], oracle: dict, meta: dict) -> str:
    lines = [
        "# W1 identification benchmark, fixed orders",
        "",
        f"T = {T} estimation + {T} validation samples; fit % = validation simulation fit from rest "
        "(mean over outputs); oracle = noise-free truth vs measured. Every tool runs in fresh "
        "processes (`nice -n 5`); times are of the fit call (imports and data excluded), wall s "
        "and CPU s (user + system of the process, all threads) in brackets. jthermo: **cold** = "
        "first call in a process with an empty persistent compilation cache (`jthermo.runtime`), "
        "**cached** = first call of a second process reading the cache the first wrote (a "
        "user's repeat `jthermo fit`), **warm** = second call in the first process. Peers: cold "
        "= first call, warm = second call (they compile nothing; one call only where it took "
        f"more than {PEER_WARM_MAX_CPU:.0f} CPU s: warm = cold). Speed-up = peer s / jthermo s, "
        "cold / cached / warm (the peer's cold time against jthermo's cold and cached, warm "
        "against warm), by wall and by CPU s; on the shared machine the CPU ratio is the "
        "load-robust one. OE and BJ: one denominator per output shared by its inputs "
        "(`common_f=True`, SIPPY's MIMO structure). Output level at rest: "
        + ("estimated by jthermo (`rest_level=None`; SIPPY, fitting the raw data, takes 0). "
           if REST_LEVEL is None else
           "0 °C for ARX/ARMAX/OE/BJ/N4SID (`rest_level=0`: W1's outputs are °C above ambient "
           "and start at ambient, which SIPPY assumes too by fitting the raw data). ")
        + "N4SID = subspace estimate only (order N, 20 block rows; N4SID weighting, "
        "`weighting=\"n4sid\"`, as SIPPY's method; before 2026-11-24 22:40 UTC jthermo's "
        "default CVA); SS = N4SID start + PEM "
        "of the simulation error (order N; MATLAB `ssest` with focus simulation), against "
        "jax-sysid's simulation-error fit configured as its documentation recommends (scaled "
        "data, rho_th 1e-2, rho_x0 1e-3, 1000 L-BFGS epochs; `benchmarks/peers_fair.py` 'doc'). "
        "Peers run in their own environment (`make bench-peers`: "
        "`benchmarks/requirements-peers.txt`). Load = 1-minute load average when the row "
        "finished (2-core machine shared with other jobs). Every tool runs with one BLAS "
        "thread (OPENBLAS_NUM_THREADS=1). ARMAX/OE/BJ: `jthermo` = the default "
        "(`engine=\"auto\"`: `polynomial.choose_engine`, the engine that ran in the note), "
        "`jthermo jax` = the compiled PEM, `jthermo numpy` = `fit(..., engine=\"numpy\")`, the "
        "same criterion, starts and screening solved in NumPy (`jthermo/identify/pem_numpy.py`), "
        "nothing compiled.",
        "",
        f"Machine: {meta['machine']}; {meta['date']}; command: `{meta['command']}`",
        "",
        ("| family | N | tool | cold s (CPU) | cached s (CPU) | warm s (CPU) | fit % | oracle % "
         "| speed-up by wall, cold / cached / warm | by CPU s | load | note |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    jt: dict = {}
    for r in rows:
        if r["tool"].startswith("jthermo"):
            jt.setdefault((r["family"], r["N"]), []).append(r)

    def cell(r, key):
        return f"{_fmt(r.get(key + '_s'))} ({_fmt(r.get(key + '_cpu'))})"

    for r in rows:
        ref = jt.get((r["family"], r["N"]), [])
        note = "; ".join(n for n in (r.get("error", r.get("note", "")),
                                     f"engine {r['engine_used']}" if r.get("engine_used") else "") if n)
        cached = cell(r, "cached") if r["tool"].startswith("jthermo") else "—"
        lines.append(f"| {r['family'].upper()} | {r['N']} | {r['tool']} | {cell(r, 'cold')} | "
                     f"{cached} | {cell(r, 'warm')} | {_fmt(r.get('fit'), 3)} | "
                     f"{_fmt(oracle[r['N']], 1)} | {_speedups(r, ref, 's')} | "
                     f"{_speedups(r, ref, 'cpu')} | {_fmt(r.get('load'), 1)} | {note} |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- default path


def write_default_records(W, N: int, seed: int, folder: Path) -> tuple[dict, dict]:
    """The default-path W1 records (6000 estimation + 3000 validation samples, absolute °C with
    the ambient at 25 °C) written as `folder/est.csv` and `folder/val.csv`; returns both."""
    from jthermo.data import from_arrays, save_csv

    est, val = W.make_dataset(N, 6000, seed, 1), W.make_dataset(N, 3000, seed, 2)
    for name, d in (("est", est), ("val", val)):
        save_csv(from_arrays(d["u"], 25.0 + d["y"]), folder / f"{name}.csv")
    return est, val


def with_noise(W, std: float | None = None, pole: float | None = None):
    """W1 with another coloured sensor noise (std °C, AR(1) pole); None keeps W1's own. The
    shared module reads its module constants, the re-creation its class attributes: both are
    set on the object `load_workloads` returned."""
    for name, value in (("NOISE_STD", std), ("NOISE_POLE", pole)):
        if value is not None:
            setattr(W, name, float(value))
    return W


def shell_fit(tmp: Path, fam: str, tag: str, extra=(), pythonpath: Path | None = None) -> dict:
    """`jthermo fit tmp/est.csv --model fam --validation tmp/val.csv --json ...` in a fresh
    process with an empty compilation cache (`tmp/cache_<tag>`), under /usr/bin/time, started
    in `tmp`; `extra`: more CLI arguments; `pythonpath`: import `jthermo` from there (another
    source tree) instead of the installed one. Returns exit, wall_s, cpu_s (user + system),
    peak_rss_mb, load_before / load (1-minute) and from the report orders, fit, converged,
    repaired, converged_outputs (or error: stderr's last line)."""
    import subprocess

    js, tm = tmp / f"{tag}.json", tmp / f"{tag}.time"
    env = {**os.environ, "JTHERMO_CACHE_DIR": str(tmp / f"cache_{tag}")}
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    cmd = ["/usr/bin/time", "-f", "%e %M %U %S", "-o", str(tm), str(ROOT / ".venv/bin/jthermo"),
           "fit", str(tmp / "est.csv"), "--model", fam, "--validation", str(tmp / "val.csv"),
           "--json", str(js), *extra]
    load0 = os.getloadavg()[0]
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False, cwd=tmp)
    wall, rss, user, system = (float(v) for v in tm.read_text().split()[-4:])
    row = {"exit": p.returncode, "wall_s": wall, "cpu_s": user + system,
           "peak_rss_mb": rss / 1024, "load_before": load0, "load": os.getloadavg()[0]}
    if p.returncode == 0:
        r = json.loads(js.read_text())
        row.update(orders=r["orders"], fit=r["mean_fit_percent"], converged=r["converged"],
                   engine_used=r.get("engine"),
                   repaired=r.get("repaired"), converged_outputs=r.get("converged_outputs"))
    else:
        row["error"] = (p.stderr.strip().splitlines() or [""])[-1][:160]
    return row


def default_path(W, Ns, families, seed: int = 0, out: Path | None = None,
                 engine: str = "auto", prior: list[dict] = ()) -> list[dict]:
    """What a user meets: `jthermo fit EST.csv --model M --validation VAL.csv --json OUT` with
    automatic orders, in a fresh process with an empty compilation cache (JTHERMO_CACHE_DIR),
    on W1 records in absolute °C (ambient 25 °C, 6000 estimation + 3000 validation samples).
    Wall time and peak RSS from /usr/bin/time; gap = validation fit minus the true model's
    (the noise-free W1 plant simulated from rest vs measured). `engine`: `--engine` for
    armax/oe/bj (`"auto"`: the default, no flag). `prior`: rows of earlier calls, kept first in
    `out`'s table."""
    import tempfile

    from jthermo.data import atomic_write_text

    rows = list(prior)
    for N in Ns:
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            est, val = write_default_records(W, N, seed, tmp)
            truth = W.fit_percent(val["y"], val["y_clean"])
            for fam in families:
                print(f"[default path] N={N} {fam} ...", file=sys.stderr, flush=True)
                extra = ["--engine", engine] if engine != "auto" and fam in ENGINE_FAMILIES else []
                row = {"family": fam, "N": N, **shell_fit(tmp, fam, fam, extra), "true_fit": truth,
                       "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default"),
                       "seed": seed, "noise_std": W.NOISE_STD, "noise_pole": W.NOISE_POLE,
                       "engine": engine if fam in ENGINE_FAMILIES else "—"}
                if "fit" in row:
                    row["gap"] = row["fit"] - truth
                rows.append(row)
                if out is not None:
                    atomic_write_text(out.with_suffix(".json"), json.dumps(rows, indent=1))
                    atomic_write_text(out, default_markdown(rows))
    return rows


def default_markdown(rows: list[dict]) -> str:
    intro = ("W1 records in absolute °C (6000 + 3000 samples, Ts = 1 s), fresh process and empty "
             "compilation cache per row; wall, CPU (user + system) and peak RSS by /usr/bin/time; "
             "gap = validation fit (MATLAB compare, initial state estimated) minus the true "
             "model's fit; load = 1-minute load average before / after the row (2-core machine "
             "shared with other jobs: wall times grow with the load, CPU seconds much less). "
             "OpenBLAS threads: OPENBLAS_NUM_THREADS as this script sets it (1 unless set before "
             f"it ran; here {os.environ.get('OPENBLAS_NUM_THREADS', 'default')}): a shell without "
             "it uses one thread per core, which made small LAPACK calls much slower under load.")
    records = (f"Records: W1 seed {rows[0].get('seed', 0)}, coloured sensor noise std "
               f"{_fmt(rows[0].get('noise_std', 0.1), 3)} °C, AR(1) pole "
               f"{_fmt(rows[0].get('noise_pole', 0.7), 2)}.")
    lines = markdown_table_head(
        "Default path: `jthermo fit` with automatic orders, cold, from the shell",
        [intro, records],
        ["family", "N", "orders", "fit %", "true %", "gap", "converged", "wall s", "CPU s",
         "peak RSS MB", "load", "note"])
    for r in rows:
        o = " ".join(f"{k} {v}" for k, v in (r.get("orders") or {}).items())
        rows_ok = r.get("converged_outputs") or []
        note = "; ".join(n for n in (
            r.get("error") or r.get("repaired") or "",
            f"engine {r['engine']}" + (f" → {r['engine_used']}" if r.get("engine_used") else "")
            if r.get("engine", "—") != "—" else "",
            f"{sum(rows_ok)}/{len(rows_ok)} outputs converged" if not all(rows_ok) else "") if n)
        lines.append(f"| {r['family']} | {r['N']} | {o} | {_fmt(r.get('fit'))} | {_fmt(r['true_fit'])} | "
                     f"{_fmt(r.get('gap'))} | {r.get('converged', '—')} | {_fmt(r['wall_s'], 1)} | "
                     f"{_fmt(r.get('cpu_s'), 1)} | {_fmt(r['peak_rss_mb'], 0)} | "
                     f"{_fmt(r.get('load_before'), 1)} / {_fmt(r['load'], 1)} | {note} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="N = 4 only; skip SIPPY OE and BJ")
    ap.add_argument("--peers", choices=("none", "sippy", "all"), default="all")
    ap.add_argument("--n", type=int, nargs="+", default=None, help="zone counts (default 4 16)")
    ap.add_argument("--families", nargs="+", default=list(FAMILIES),
                    choices=FAMILIES + ("greybox",), help="greybox: --default-path only")
    ap.add_argument("--peer-timeout", type=float, default=900.0, help="s per child process")
    ap.add_argument("--peer-python", default=str(PEERS_PYTHON),
                    help="python of the peers' environment (`make bench-peers`)")
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    ap.add_argument("--peer-families", nargs="+", default=list(FAMILIES), choices=FAMILIES,
                    help="families the peers are run for (SIPPY OE/BJ are slow)")
    ap.add_argument("--engines", nargs="+", default=["auto"], choices=("auto", "jax", "numpy"),
                    help="jthermo PEM engines timed for armax/oe/bj (fit_polynomial(engine=...); "
                    "auto: the default)")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    ap.add_argument("--out", type=Path, default=RESULTS / "identification.md")
    ap.add_argument("--estimate-level", action="store_true",
                    help="jthermo estimates the rest level instead of taking W1's 0 °C")
    ap.add_argument("--default-path", action="store_true",
                    help="time `jthermo fit` with automatic orders from the shell (cold), per --n "
                    "and --families; writes results/identification_default_path.md/.json")
    ap.add_argument("--seed", type=int, default=0,
                    help="--default-path: W1 seed of the plant and records (held-back checks use "
                    "seeds never used in development)")
    ap.add_argument("--noise-std", type=float, default=None,
                    help="--default-path: stationary std of W1's coloured sensor noise, °C "
                    "(W1: 0.1)")
    ap.add_argument("--noise-pole", type=float, default=None,
                    help="--default-path: AR(1) pole of that noise (W1: 0.7)")
    args = ap.parse_args(argv)
    global REST_LEVEL
    if args.child:   # jthermo FAMILY N CACHE zero|estimated warm|cold ENGINE, or peer TOOL FAMILY N
        kind, *rest = args.child
        if kind == "jthermo":
            REST_LEVEL = 0.0 if rest[3] == "zero" else None
            row = jthermo_child(rest[0], int(rest[1]), rest[2], warm=rest[4] == "warm",
                                engine=rest[5] if len(rest) > 5 else "auto")
        else:
            row = peer_child(rest[0], rest[1], int(rest[2]))
        print(json.dumps(row), flush=True)
        return 0
    if args.default_path:
        fams = [f for f in args.families if f != "n4sid"]
        W = with_noise(load_workloads(), args.noise_std, args.noise_pole)
        rows = []
        for engine in args.engines:
            rows = default_path(W, args.n or [4], fams, seed=args.seed, engine=engine,
                                out=RESULTS / "identification_default_path.md", prior=rows)
        return 0
    if "greybox" in args.families:
        ap.error("--families greybox: only with --default-path (no fixed-order W1 grey-box)")
    if args.estimate_level:
        REST_LEVEL = None
    Ns = args.n or ([4] if args.quick else [4, 16])
    W = load_workloads()
    rows, oracle = [], {}
    meta = {"machine": f"{platform.machine()}, {os.cpu_count()} CPU cores, {platform.python_version()}",
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "command": "".join(f"{v}={os.environ[v]} " for v in ("XLA_FLAGS",) if os.environ.get(v))
            + "python benchmarks/identification.py " + " ".join(argv or sys.argv[1:])}
    from jthermo.data import atomic_write_text

    def save():   # after every row, so a stopped run still leaves its table
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, markdown(rows, oracle, meta))
        if args.json:
            clean = [{k: v for k, v in r.items() if k != "trace"} for r in rows]
            atomic_write_text(args.json, json.dumps({"rows": clean, "oracle": oracle, **meta},
                                                    indent=1))

    for N in Ns:
        _, val = W.estimation_validation(N, T, 0)
        oracle[N] = W.fit_percent(val["y"], val["y_clean"])
        for fam in args.families:
            for engine in args.engines if fam in ENGINE_FAMILIES else ["auto"]:
                print(f"[W1] N={N} {fam}: {jthermo_tool(engine)} ...", file=sys.stderr, flush=True)
                rows.append(run_jthermo(fam, N, args.peer_timeout, engine))
                save()
            if args.peers in ("sippy", "all") and fam in SIPPY_METHOD:
                if (args.quick and fam in ("oe", "bj")) or fam not in args.peer_families:
                    rows.append({"tool": "SIPPY", "family": fam, "N": N, "note": "skipped"})
                else:
                    print(f"[W1] N={N} {fam}: SIPPY ...", file=sys.stderr, flush=True)
                    rows.append(run_peer(args.peer_python, "SIPPY", fam, N, args.peer_timeout))
                    save()
            if args.peers == "all" and fam == "ss" and fam in args.peer_families:
                print(f"[W1] N={N} ss: jax-sysid ...", file=sys.stderr, flush=True)
                rows.append(run_peer(args.peer_python, "jax-sysid", fam, N,
                                     args.peer_timeout))
                save()
    save()
    print(markdown(rows, oracle, meta))
    return 0


if __name__ == "__main__":
    sys.exit(main())
