"""pytest plugin: when each test starts and ends, on which xdist worker, and how long JAX spent
making its programs, to a JSON lines file.

    JTHERMO_TIMELINE=out.jsonl PYTHONPATH=benchmarks pytest -p test_timeline ...
Each line: worker, test node id, start and end (time.time(), setup and teardown included), the
CPU seconds the test took (user + sys of the worker and the subprocesses it waited for: a
file's cost on a loaded machine, where wall time also counts the other processes), and the
seconds and counts of JAX's program-making events in the worker during the test (tracing,
lowering to MLIR, the backend compile — a read from the persistent cache included — and that
read alone), with each backend compile's seconds (`compiles`). A subprocess's programs are not
seen. `benchmarks/test_timeline_summary.py` sums them by file and shows each worker's idle tail."""
import json
import os
import threading
import time

import jax.monitoring

#: JAX's duration events, by the short name the summary uses
EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "compile",
          "/jax/compilation_cache/cache_retrieval_time_sec": "cache_read"}

_starts: dict[str, tuple[float, float, dict, int]] = {}
_totals = {name: [0.0, 0] for name in EVENTS.values()}
_compiles: list[float] = []
_lock = threading.Lock()


def _on_duration(event: str, duration: float, **_) -> None:
    name = EVENTS.get(event)
    if name is None:
        return
    with _lock:
        _totals[name][0] += duration
        _totals[name][1] += 1
        if name == "compile":
            _compiles.append(duration)


jax.monitoring.register_event_duration_secs_listener(_on_duration)


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def pytest_runtest_logstart(nodeid, location):
    with _lock:
        snap = {k: tuple(v) for k, v in _totals.items()}
        n = len(_compiles)
    _starts[nodeid] = (time.time(), _cpu(), snap, n)


def pytest_runtest_logfinish(nodeid, location):
    path = os.environ.get("JTHERMO_TIMELINE")
    if not path:
        return
    start, cpu, snap, n = _starts.pop(nodeid, (None, None, None, None))
    row = {"worker": os.environ.get("PYTEST_XDIST_WORKER", "main"), "test": nodeid,
           "start": start, "end": time.time(), "cpu": None if cpu is None else _cpu() - cpu}
    if snap is not None:
        with _lock:
            row["jax"] = {k: [v[0] - snap[k][0], v[1] - snap[k][1]] for k, v in _totals.items()}
            row["compiles"] = _compiles[n:]
    with open(path, "a") as f:
        f.write(json.dumps(row) + "\n")
