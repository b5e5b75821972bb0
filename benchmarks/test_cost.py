"""pytest plugin: each test's CPU seconds and where JAX spent them, to a JSON lines file.

    JTHERMO_TEST_COST=out.jsonl PYTHONPATH=benchmarks pytest -p test_cost ...
Each line: test node id, wall and process CPU seconds (setup, call and teardown), and the sums
of JAX's compile events during it: tracing to a jaxpr, lowering to MLIR, XLA's backend compile
(on a persistent-cache hit the backend compile is replaced by a load, `cache_hits` counts them)."""
import json
import os
import time

import jax.monitoring as mon

_EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace_s",
           "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
           "/jax/core/compile/backend_compile_duration": "backend_s"}
_acc: dict[str, float] = {}
_start: dict[str, tuple[float, float]] = {}


def _on_duration(event, secs, **kw):
    key = _EVENTS.get(event)
    if key:
        _acc[key] = _acc.get(key, 0.0) + secs
        if key == "backend_s":
            _acc["compiles"] = _acc.get("compiles", 0) + 1


def _on_event(event, **kw):
    if event == "/jax/compilation_cache/cache_hits":
        _acc["cache_hits"] = _acc.get("cache_hits", 0) + 1


mon.register_event_duration_secs_listener(_on_duration)
mon.register_event_listener(_on_event)


def pytest_runtest_logstart(nodeid, location):
    _acc.clear()
    _start[nodeid] = (time.time(), time.process_time())


def pytest_runtest_logfinish(nodeid, location):
    path = os.environ.get("JTHERMO_TEST_COST")
    w0, c0 = _start.pop(nodeid, (time.time(), time.process_time()))
    if not path:
        return
    row = {"test": nodeid, "wall_s": round(time.time() - w0, 3), "cpu_s": round(time.process_time() - c0, 3),
           **{k: round(v, 3) for k, v in _acc.items()}}
    with open(path, "a") as f:
        f.write(json.dumps(row) + "\n")
