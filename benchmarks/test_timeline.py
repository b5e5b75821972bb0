"""pytest plugin: when each test starts and ends, on which xdist worker, to a JSON lines file.

    JTHERMO_TIMELINE=out.jsonl PYTHONPATH=benchmarks pytest -p test_timeline ...
Each line: worker, test node id, start and end (time.time(), setup and teardown included).
`benchmarks/test_timeline_summary.py` sums them by file and shows each worker's idle tail."""
import json
import os
import time

_starts: dict[str, float] = {}


def pytest_runtest_logstart(nodeid, location):
    _starts[nodeid] = time.time()


def pytest_runtest_logfinish(nodeid, location):
    path = os.environ.get("JTHERMO_TIMELINE")
    if not path:
        return
    row = {"worker": os.environ.get("PYTEST_XDIST_WORKER", "main"), "test": nodeid,
           "start": _starts.pop(nodeid, None), "end": time.time()}
    with open(path, "a") as f:
        f.write(json.dumps(row) + "\n")
