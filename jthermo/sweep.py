"""Sweeps: grid or random search over identification orders, controller families, tuning weights.

A sweep is a TOML file (or the embedded `DEFAULT_CONFIG`):

```toml
[sweep]
name = "arx-orders"
kind = "arx"            # trial kind: "arx" (fast least squares), "identify", "tune"
method = "grid"         # or "random" (then `samples` draws)
samples = 20
seed = 0
objective = "mean_fit_percent"
direction = "max"       # or "min"

[data]                  # kind-specific settings shared by every trial
zones = 2
duration = 600

[space]                 # one list per parameter (grid: the Cartesian product)
na = [1, 2, 3]
nb = [1, 2]
nk = [0, 1]
```

In a random sweep a parameter may also be a range table `{low = 1e-3, high = 1.0, log = true}`
(floats) or `{low = 1, high = 5}` (integers). Each trial has a stable id (a hash of its
parameters), runs locally (in-process, or a process pool with `workers > 1`) or as a Ray task
(`ray_address`), and its result is appended to a JSON-lines file as soon as it finishes
(flushed and fsynced). Re-running the same sweep skips the trial ids already in the file, so a
killed sweep resumes without redoing or losing finished trials.
"""

from __future__ import annotations

import concurrent.futures as cf
import copy
import hashlib
import itertools
import json
import math
import multiprocessing
import os
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ConfigError, JThermoError

KINDS = ("arx", "identify", "tune")

DEFAULT_CONFIG = """
# The embedded default: ARX orders on a simulated two-zone bed, then read the best ones.
[sweep]
name = "default"
kind = "arx"
method = "grid"
seed = 0
objective = "mean_fit_percent"
direction = "max"

[data]
zones = 2
samples = 2000
noise = 0.05

[space]
na = [1, 2, 3, 4]
nb = [1, 2, 3, 4]
nk = [0, 1, 2]
"""

_DEFAULTS = {"method": "grid", "samples": 10, "seed": 0, "objective": None, "direction": None}
_OBJECTIVES = {"arx": ("mean_fit_percent", "max"), "identify": ("mean_fit_percent", "max"),
               "tune": ("tuned_cost", "min")}


# ---------------------------------------------------------------- configuration


def parse_config(text: str, source: str = "config") -> dict:
    """Parse and check a sweep configuration (TOML text)."""
    import tomllib

    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML ({exc})") from None
    return check_config(raw, source)


def load_config(path: str | os.PathLike) -> dict:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such file") from None
    except (UnicodeDecodeError, IsADirectoryError):
        raise ConfigError(f"{p}: not a text TOML file") from None
    return parse_config(text, str(p))


def default_config() -> dict:
    """The embedded default sweep (fast ARX order grid on simulated data)."""
    return parse_config(DEFAULT_CONFIG, "default config")


def check_config(raw: dict, source: str = "config") -> dict:
    sweep = raw.get("sweep")
    if not isinstance(sweep, dict):
        raise ConfigError(f"{source}: missing [sweep] table")
    unknown = set(raw) - {"sweep", "data", "space", "fixed"}
    if unknown:
        raise ConfigError(f"{source}: unknown table [{sorted(unknown)[0]}] (expected sweep, data, space, fixed)")
    cfg = {**_DEFAULTS, **sweep}
    bad = set(cfg) - {"name", "kind", *_DEFAULTS}
    if bad:
        raise ConfigError(f"{source}: unknown key `{sorted(bad)[0]}` in [sweep]")
    if not isinstance(cfg.get("name"), str) or not cfg["name"] or "/" in cfg["name"]:
        raise ConfigError(f"{source}: [sweep] needs a plain `name`")
    if cfg.get("kind") not in KINDS:
        raise ConfigError(f"{source}: [sweep] kind must be one of {', '.join(KINDS)}, got {cfg.get('kind')!r}")
    if cfg["method"] not in ("grid", "random"):
        raise ConfigError(f"{source}: [sweep] method must be 'grid' or 'random', got {cfg['method']!r}")
    if not isinstance(cfg["samples"], int) or not 1 <= cfg["samples"] <= 100000:
        raise ConfigError(f"{source}: [sweep] samples must be an integer in 1..100000")
    if not isinstance(cfg["seed"], int):
        raise ConfigError(f"{source}: [sweep] seed must be an integer")
    obj, direction = _OBJECTIVES[cfg["kind"]]
    cfg["objective"] = cfg["objective"] or obj
    cfg["direction"] = cfg["direction"] or direction
    if cfg["direction"] not in ("min", "max"):
        raise ConfigError(f"{source}: [sweep] direction must be 'min' or 'max'")
    space = raw.get("space")
    if not isinstance(space, dict) or not space:
        raise ConfigError(f"{source}: missing or empty [space] table")
    for k, v in space.items():
        if isinstance(v, list):
            if not v:
                raise ConfigError(f"{source}: [space] `{k}` is an empty list")
        elif isinstance(v, dict):
            if cfg["method"] != "random":
                raise ConfigError(f"{source}: [space] `{k}` is a range; ranges need method = 'random'")
            if not {"low", "high"} <= set(v) or not all(isinstance(v[b], (int, float)) for b in ("low", "high")) \
                    or not v["low"] <= v["high"]:
                raise ConfigError(f"{source}: [space] `{k}` range needs numbers low <= high")
            if v.get("log") and v["low"] <= 0:
                raise ConfigError(f"{source}: [space] `{k}` log range needs low > 0")
        else:
            raise ConfigError(f"{source}: [space] `{k}` must be a list of values or a range table")
    cfg["data"] = dict(raw.get("data", {}))
    cfg["fixed"] = dict(raw.get("fixed", {}))
    cfg["space"] = space
    n = count_trials(cfg)
    if n > 100000:
        raise ConfigError(f"{source}: the grid has {n} trials (more than 100000)")
    return cfg


def count_trials(cfg: dict) -> int:
    if cfg["method"] == "random":
        return cfg["samples"]
    return math.prod(len(v) for v in cfg["space"].values())


# ---------------------------------------------------------------- trials


def trial_id(params: dict) -> str:
    """A stable id: the first 12 hex digits of the SHA-1 of the sorted JSON parameters."""
    return hashlib.sha1(json.dumps(params, sort_keys=True).encode()).hexdigest()[:12]


def trials(cfg: dict) -> list[dict]:
    """The sweep's trials, each `{"id", "params"}`, in a deterministic order."""
    space = cfg["space"]
    names = sorted(space)
    out = []
    if cfg["method"] == "grid":
        for combo in itertools.product(*(space[n] for n in names)):
            params = {**cfg["fixed"], **dict(zip(names, combo))}
            out.append({"id": trial_id(params), "params": params})
    else:
        rng = np.random.default_rng(cfg["seed"])
        seen = set()
        for _ in range(cfg["samples"]):
            params = dict(cfg["fixed"])
            for n in names:
                v = space[n]
                if isinstance(v, list):
                    params[n] = v[int(rng.integers(len(v)))]
                elif isinstance(v["low"], int) and isinstance(v["high"], int) and not v.get("log"):
                    params[n] = int(rng.integers(v["low"], v["high"] + 1))
                elif v.get("log"):
                    params[n] = float(math.exp(rng.uniform(math.log(v["low"]), math.log(v["high"]))))
                else:
                    params[n] = float(rng.uniform(v["low"], v["high"]))
            tid = trial_id(params)
            if tid not in seen:
                seen.add(tid)
                out.append({"id": tid, "params": params})
    return out


def _simulated_arx_data(settings: dict):
    """A small, deterministic multi-zone data set: a 2nd-order coupled bed with noise."""
    zones = int(settings.get("zones", 2))
    T = int(settings.get("samples", 2000))
    noise = float(settings.get("noise", 0.05))
    seed = int(settings.get("data_seed", 0))
    rng = np.random.default_rng(seed)
    # input: random binary levels held for 5..30 samples per channel
    u = np.empty((T, zones))
    for j in range(zones):
        k = 0
        while k < T:
            h = int(rng.integers(5, 31))
            u[k:k + h, j] = rng.choice([0.2, 0.6])
            k += h
    A1 = 1.6 * np.eye(zones)
    A2 = -0.64 * np.eye(zones) + 0.01 * (np.ones((zones, zones)) - np.eye(zones))
    B = 0.5 * np.eye(zones) + 0.1 * (np.ones((zones, zones)) - np.eye(zones))
    y = np.zeros((T, zones))
    for k in range(2, T):
        y[k] = A1 @ y[k - 1] + A2 @ y[k - 2] + B @ u[k - 2]
    y = y + 20.0 + noise * rng.standard_normal((T, zones))
    return u, y


def _arx_trial(params: dict, settings: dict) -> dict:
    """Diagonal MISO ARX by least squares (numpy only: fast, no compile), simulation fit on the
    second half of the data."""
    na, nb, nk = int(params.get("na", 2)), int(params.get("nb", 2)), int(params.get("nk", 1))
    if na < 0 or nb < 1 or nk < 0:
        raise ConfigError(f"arx trial: invalid orders na={na}, nb={nb}, nk={nk}")
    if "data" in settings:
        from .data import load

        d = load(settings["data"])
        u, y = d.u, d.y
    else:
        u, y = _simulated_arx_data(settings)
    T, ny = y.shape
    nu = u.shape[1]
    half = T // 2
    u_mean, y_mean = u[:half].mean(0), y[:half].mean(0)
    du, dy = u - u_mean, y - y_mean
    lag = max(na, nb + nk - 1, 1)
    fits = []
    n_params = na + nb * nu
    for i in range(ny):
        rows = range(lag, half)
        X = np.array([[-dy[k - j, i] for j in range(1, na + 1)]
                      + [du[k - nk - j, m] for m in range(nu) for j in range(nb)] for k in rows])
        theta, *_ = np.linalg.lstsq(X, dy[lag:half, i], rcond=None)
        a, b = theta[:na], theta[na:].reshape(nu, nb)
        # simulate on the validation half from the measured initial lags
        ysim = dy[:, i].copy()
        for k in range(half, T):
            ysim[k] = -sum(a[j - 1] * ysim[k - j] for j in range(1, na + 1)) + sum(
                b[m, j] * du[k - nk - j, m] for m in range(nu) for j in range(nb))
        yv, ys = dy[half:, i], ysim[half:]
        fits.append(float(100.0 * (1.0 - np.linalg.norm(yv - ys) / np.linalg.norm(yv - yv.mean()))))
    fits = [f if math.isfinite(f) else -1e9 for f in fits]
    return {"fit_percent": fits, "mean_fit_percent": float(np.mean(fits)), "n_params": n_params}


def _identify_trial(params: dict, settings: dict) -> dict:
    from . import data as data_mod
    from .identify.fit import fit
    from .validate import compare

    family = params.get("family", settings.get("family", "arx"))
    from .identify.fit import ORDER_NAMES

    names = ORDER_NAMES.get(family, ())
    given = [n for n in names if n in params]
    if given and len(given) != len(names):
        raise ConfigError(f"identify trial: {family} needs all of the orders {', '.join(names)}")
    orders = tuple(int(params[n]) for n in names) if given else None
    if "data" in settings:
        est = data_mod.load(settings["data"])
        val = data_mod.load(settings["validation"]) if "validation" in settings else None
    else:
        from .printer import generate, make_printer

        p = make_printer(int(settings.get("zones", 2)), tuple(settings.get("effects", ())),
                         seed=int(settings.get("data_seed", 0)))
        est = generate(p, "prbs", float(settings.get("duration", 1200)), seed=int(settings.get("data_seed", 0)))
        val = None
    if val is None:
        est, val = data_mod.split(est, 0.5)
    res = fit(est, family, orders, seed=int(params.get("seed", 0)))
    cmp = compare(res.model, val)
    return {"family": family, "orders": dict(res.orders or {}),
            "fit_percent": cmp["fit_percent"], "mean_fit_percent": cmp["mean_fit_percent"],
            "converged": bool(getattr(res, "converged", True))}


def _tune_trial(params: dict, settings: dict) -> dict:
    from .tune import tune_report

    family = params.get("controller", settings.get("controller", "pi_lambda"))
    kwargs = {k: v for k, v in params.items() if k not in ("controller",)}
    weights = {k[len("w_"):]: float(v) for k, v in kwargs.items() if k.startswith("w_")}
    extra: dict[str, Any] = {}
    if weights:
        extra["weights"] = weights
    rep = tune_report(family, plant=settings.get("plant", "printer"), model=None,
                      rollouts=int(params.get("rollouts", settings.get("rollouts", 8))),
                      steps=int(params.get("steps", settings.get("steps", 20))),
                      seed=int(params.get("seed", settings.get("seed", 0))), progress=None, **extra)
    return {k: v for k, v in rep.items() if isinstance(v, (int, float, str, bool, list, dict, type(None)))}


_TRIAL_FUNCS: dict[str, Callable[[dict, dict], dict]] = {
    "arx": _arx_trial, "identify": _identify_trial, "tune": _tune_trial}


def run_trial(kind: str, trial: dict, settings: dict) -> dict:
    """Run one trial; never raises: failures are recorded with their one-line reason."""
    t0 = time.perf_counter()
    record: dict[str, Any] = {"id": trial["id"], "params": trial["params"], "kind": kind}
    try:
        if kind != "arx":
            import jax

            jax.config.update("jax_enable_x64", True)  # a worker process: identification needs float64
        metrics = _TRIAL_FUNCS[kind](trial["params"], settings)
        record.update(status="ok", metrics=_clean(metrics))
    except JThermoError as exc:
        record.update(status="error", error=" ".join(str(exc).split()))
    except Exception as exc:  # noqa: BLE001 - one failing trial must not stop a sweep
        record.update(status="error", error=f"{type(exc).__name__}: {' '.join(str(exc).split())}",
                      where=traceback.format_exc(limit=2).splitlines()[-1][:200])
    record["seconds"] = time.perf_counter() - t0
    record["finished_at"] = time.time()
    return record


def _clean(x):
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.generic, np.ndarray)):
        return _clean(np.asarray(x).tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


# ---------------------------------------------------------------- results file


def default_results_path(cfg: dict) -> Path:
    return Path("runs") / "sweeps" / f"{cfg['name']}.jsonl"


def read_results(path: str | os.PathLike) -> list[dict]:
    """Every complete record of a results file (a torn last line from a kill is ignored)."""
    p = Path(path)
    if not p.exists():
        return []
    out = []
    with open(p, encoding="utf-8", errors="replace") as f:
        for line in f:
            if not line.endswith("\n"):
                break  # torn write
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(rec, dict) and "id" in rec:
                out.append(rec)
    return out


def _repair_tail(p: Path) -> None:
    """Drop a torn last line (a kill in the middle of a write) so appends start on a new line."""
    if not p.exists() or p.stat().st_size == 0:
        return
    with open(p, "rb+") as f:
        data = f.read()
        if data.endswith(b"\n"):
            return
        cut = data.rfind(b"\n") + 1
        f.truncate(cut)
        f.flush()
        os.fsync(f.fileno())


def append_result(path: Path, record: dict) -> None:
    line = json.dumps(record, sort_keys=True, allow_nan=False) + "\n"
    with open(path, "a", encoding="utf-8") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


def _score(rec: dict, cfg: dict) -> float | None:
    v = rec.get("metrics", {}).get(cfg["objective"]) if rec.get("status") == "ok" else None
    return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None


def best_trials(rows: list[dict], cfg: dict | None, top: int = 10) -> list[dict]:
    """The `top` finished trials by the objective (latest record per id)."""
    if cfg is None:
        cfg = default_config()
    latest = {r["id"]: r for r in rows}
    scored = [(s, r) for r in latest.values() if (s := _score(r, cfg)) is not None]
    scored.sort(key=lambda sr: sr[0], reverse=cfg["direction"] == "max")
    return [{"id": r["id"], "params": r["params"], "score": s, "seconds": r.get("seconds")}
            for s, r in scored[:top]]


def format_summary(best: list[dict], cfg: dict, total: int | None = None) -> str:
    head = f"best {len(best)} of {total if total is not None else '?'} trials by {cfg['objective']} ({cfg['direction']}):"
    if not best:
        return head + "\n  (no finished trials)"
    lines = [head]
    for i, b in enumerate(best, 1):
        params = ", ".join(f"{k}={v}" for k, v in sorted(b["params"].items()))
        lines.append(f"{i:3d}. {b['score']:.4g}  [{b['id']}]  {params}")
    return "\n".join(lines)


# ---------------------------------------------------------------- execution


def _probe(address: str, timeout: float = 5.0) -> None:
    """Fail fast (instead of Ray's long retry loop) when nothing listens at `host:port`."""
    import socket

    hostport = address.split("://", 1)[-1]
    host, _, port = hostport.rpartition(":")
    try:
        port_n = int(port)
    except ValueError:
        raise ConfigError(f"--ray {address}: expected host:port, 'local' or 'auto'") from None
    try:
        with socket.create_connection((host or "127.0.0.1", port_n), timeout=timeout):
            pass
    except OSError as exc:
        raise ConfigError(f"--ray {address}: cannot connect ({exc.strerror or type(exc).__name__})") from None


def _ray_run(kind, todo, settings, address, on_done):
    try:
        import ray
    except ImportError:
        raise ConfigError("--ray: the `ray` package is not installed (pip install 'jthermo[ray]')") from None
    started_here = False
    if not ray.is_initialized() and address not in (None, "", "local", "auto"):
        _probe(address)
    if not ray.is_initialized():
        try:
            if address in (None, "", "local"):
                ray.init(num_cpus=os.cpu_count() or 1, include_dashboard=False, log_to_driver=False)
            else:
                ray.init(address=address, include_dashboard=False, log_to_driver=False)
        except Exception as exc:  # noqa: BLE001 - connection failures come in many types
            raise ConfigError(f"--ray {address}: cannot connect ({type(exc).__name__}: "
                              f"{' '.join(str(exc).split())[:200]})") from None
        started_here = True
    try:
        remote = ray.remote(run_trial)
        pending = {remote.remote(kind, t, settings): t for t in todo}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                pending.pop(ref)
                on_done(ray.get(ref))
    finally:
        if started_here:
            ray.shutdown()


def run_sweep(cfg: dict, results: str | os.PathLike, *, ray_address: str | None = None,
              workers: int | None = None, progress: Callable | None = None) -> dict:
    """Run every trial of `cfg` not already in `results`, appending each result as it finishes.

    **Arguments:**
    - `cfg`: a checked configuration (`load_config`, `parse_config`, `default_config`).
    - `results`: the JSON-lines results file (created if needed, appended otherwise).
    - `ray_address`: run the trials as Ray tasks on this cluster (`"local"`: start one here).
    - `workers`: local worker processes (None or 1: in this process).
    - `progress`: a `(i, total, info)` callable.

    **Returns:** `{"name", "results", "n_total", "n_skipped", "n_run", "n_failed", "best"}`.
    """
    cfg = copy.deepcopy(cfg)
    path = Path(results)
    path.parent.mkdir(parents=True, exist_ok=True)
    _repair_tail(path)
    done_ids = {r["id"] for r in read_results(path)}
    all_trials = trials(cfg)
    todo = [t for t in all_trials if t["id"] not in done_ids]
    settings = cfg["data"]
    kind = cfg["kind"]
    counts = {"run": 0, "failed": 0}

    def on_done(rec):
        append_result(path, _clean(rec))
        counts["run"] += 1
        counts["failed"] += rec["status"] != "ok"
        if progress is not None:
            progress(counts["run"], len(todo), {"failed": counts["failed"]})

    if ray_address is not None:
        _ray_run(kind, todo, settings, ray_address, on_done)
    elif not workers or workers <= 1:
        for t in todo:
            on_done(run_trial(kind, t, settings))
    else:
        ctx = multiprocessing.get_context("spawn")  # never fork a process that holds JAX threads
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            futures = [pool.submit(run_trial, kind, t, settings) for t in todo]
            try:
                for fut in cf.as_completed(futures):
                    on_done(fut.result())
            except BaseException:
                for f in futures:
                    f.cancel()
                raise
    rows = read_results(path)
    return {"name": cfg["name"], "kind": kind, "results": str(path), "n_total": len(all_trials),
            "n_skipped": len(all_trials) - len(todo), "n_run": counts["run"],
            "n_failed": counts["failed"], "best": best_trials(rows, cfg, top=5)}
