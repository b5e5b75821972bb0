"""`runtime.busy`: a machine counts as busy from `BUSY_LOAD_PER_CPU` per CPU beyond the first
(then `jthermo simulate` makes its backend with one intra-op thread), and where the load
cannot be read."""

from __future__ import annotations

import os

import pytest

from jthermo import runtime


@pytest.mark.parametrize(("load", "cpus", "expected"),
                         [(0.3, 2, False), (0.99, 2, False), (1.0, 2, True), (5.0, 2, True),
                          (2.5, 4, False), (3.0, 4, True), (0.5, 1, False), (1.2, 1, True)])
def test_busy_follows_the_load_per_spare_cpu(monkeypatch, load, cpus, expected):
    monkeypatch.setattr(os, "getloadavg", lambda: (load, 0.0, 0.0))
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(cpus)))
    assert runtime.busy() is expected


def test_busy_where_the_load_cannot_be_read(monkeypatch):
    def unreadable():
        raise OSError("no /proc/loadavg")

    monkeypatch.setattr(os, "getloadavg", unreadable)
    assert runtime.busy() is True
