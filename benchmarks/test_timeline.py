"""pytest plugin: when each test starts and ends, on which xdist worker, to a JSON lines file.

    JTHERMO_TIMELINE=out.jsonl PYTHONPATH=benchmarks pytest -p test_timeline ...
Each line: worker, test node id, start and end (time.time(), setup and teardown included) and
the CPU seconds the test took (user + sys of the worker and the subprocesses it waited for: a
file's cost on a loaded machine, where wall time also counts the other processes).
`benchmarks/test_timeline_summary.py` sums them by file and shows each worker's idle tail."""
import json
import os
import time

_starts: dict[str, tuple[float, float]] = {}


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def pytest_runtest_logstart(nodeid, location):
    _starts[nodeid] = (time.time(), _cpu())


def pytest_runtest_logfinish(nodeid, location):
    path = os.environ.get("JTHERMO_TIMELINE")
    if not path:
        return
    start, cpu = _starts.pop(nodeid, (None, None))
    row = {"worker": os.environ.get("PYTEST_XDIST_WORKER", "main"), "test": nodeid,
           "start": start, "end": time.time(), "cpu": None if cpu is None else _cpu() - cpu}
    with open(path, "a") as f:
        f.write(json.dumps(row) + "\n")
