"""Running a sweep: the append-only JSON-lines results file (torn-line repair, resume), the
ranking of finished trials, and the execution in process, in a process pool or on Ray."""

from __future__ import annotations

import concurrent.futures as cf
import copy
import json
import math
import multiprocessing
import os
from collections.abc import Callable
from pathlib import Path

from ..errors import ConfigError
from .config import current_rows, default_config, trials
from .frames import results_frame
from .tasks import clean_json, run_trial

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
    """The `top` finished trials by the objective (latest record per id; this version's
    trials only: `current_rows`)."""
    if cfg is None:
        cfg = default_config()
    latest = {r["id"]: r for r in current_rows(rows)}
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


class SweepResult(dict):
    """The report of `run_sweep` (a plain dict, JSON-ready) that also opens its results file
    as a DataFrame: `to_dataframe()`, one row per trial, best first (`frames.results_frame`)."""

    def __init__(self, report: dict, cfg: dict):
        super().__init__(report)
        self.cfg = cfg

    def to_dataframe(self):
        return results_frame(read_results(self["results"]), self.cfg)


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


#: trials per local worker process of one pool (a pool of `workers` processes runs
#: `workers * TRIALS_PER_WORKER` trials, then fresh processes take over), and of a Ray worker
#: (`max_calls`): the compiled programs a worker gathers over trials of many record lengths
#: and orders are released with it, on top of the guard each trial runs (`programs.guard`)
TRIALS_PER_WORKER = 50


def pool_options(ctx) -> dict:
    """`ProcessPoolExecutor` arguments. Workers are recycled by `_pool_run` (a fresh pool per
    `workers * TRIALS_PER_WORKER` trials), not by `max_tasks_per_child`: on Python 3.11 a pool
    whose workers all reach their quota together replaces none of them and waits for ever
    (a 1,000-trial sweep on 2 workers stopped after trial 100)."""
    return {"mp_context": ctx}


def _pool_run(kind, todo, settings, workers: int, on_done):
    """The trials on `workers` local processes, a fresh pool for every
    `workers * TRIALS_PER_WORKER` of them (spawned: never fork a process that holds JAX
    threads)."""
    ctx = multiprocessing.get_context("spawn")
    per_pool = workers * TRIALS_PER_WORKER
    for start in range(0, len(todo), per_pool):
        with cf.ProcessPoolExecutor(max_workers=workers, **pool_options(ctx)) as pool:
            futures = [pool.submit(run_trial, kind, t, settings)
                       for t in todo[start:start + per_pool]]
            try:
                for fut in cf.as_completed(futures):
                    on_done(fut.result())
            except BaseException:
                for f in futures:
                    f.cancel()
                raise


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
        remote = ray.remote(max_calls=TRIALS_PER_WORKER)(run_trial)
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

    **Returns:** a `SweepResult`: the dict `{"name", "kind", "results", "n_total", "n_skipped",
    "n_run", "n_failed", "best"}` with `to_dataframe()`.
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
        append_result(path, clean_json(rec))
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
        _pool_run(kind, todo, settings, int(workers), on_done)
    rows = read_results(path)
    return SweepResult({"name": cfg["name"], "kind": kind, "results": str(path),
                        "n_total": len(all_trials), "n_skipped": len(all_trials) - len(todo),
                        "n_run": counts["run"], "n_failed": counts["failed"],
                        "best": best_trials(rows, cfg, top=5)}, cfg)
