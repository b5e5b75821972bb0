"""`runtime.one_thread_backend`: the CPU backend made with one intra-op thread on machines
with at most `ONE_THREAD_MAX_CPUS` CPUs, every thread given all CPUs back afterwards, nothing
done once the backend exists (in a fresh process: the test process has its backend)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from jthermo import runtime

CHILD = r"""
import json, os
from jthermo import runtime
cpus = sorted(os.sched_getaffinity(0))
first = runtime.one_thread_backend()
import jax.numpy as jnp
x = float(jnp.arange(5.0).sum())
tasks = {t: sorted(os.sched_getaffinity(int(t))) for t in os.listdir("/proc/self/task")}
print(json.dumps({"cpus": cpus, "first": first, "second": runtime.one_thread_backend(),
                  "x": x, "tasks": tasks}))
"""


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="no CPU affinities here")
def test_one_thread_backend_restores_every_thread_and_acts_once():
    r = subprocess.run([sys.executable, "-c", CHILD], check=True, capture_output=True,
                       text=True, timeout=120,
                       env={k: v for k, v in os.environ.items() if not k.startswith("JAX_")})
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["first"] == (1 < len(out["cpus"]) <= runtime.ONE_THREAD_MAX_CPUS)
    assert out["second"] is False          # the backend exists by then
    assert out["x"] == 10.0
    assert len(out["tasks"]) > 1
    assert all(c == out["cpus"] for c in out["tasks"].values()), out["tasks"]


def test_one_thread_backend_does_nothing_where_the_backend_exists():
    import jax.numpy as jnp

    jnp.zeros(1).block_until_ready()
    before = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    assert runtime.one_thread_backend() is False
    if before is not None:
        assert os.sched_getaffinity(0) == before
