"""Wall and CPU seconds of `calibrate`'s stages, for its `--json` report (`timing`).

A lap timer: `lap(name)` closes the stage that ran since the previous lap (or the start) and
names it. Per stage `wall_s`, `cpu_s` (the process's CPU seconds over the stage: every thread,
so the diagnosis running beside it counts here too, and XLA's worker threads),
`thread_cpu_s` (the calling thread's alone) and `compile_s` (the wall seconds in which some
thread traced, lowered or compiled a program: `runtime.Stopwatch`). `total` has the process's
wall and CPU seconds since the timer began; a stage run in another thread (the diagnosis) is
added with `add`.
"""

from __future__ import annotations

import time

from .. import runtime


class Laps:
    """The stages' timings (module docstring)."""

    def __init__(self) -> None:
        self._t0 = self._t = time.perf_counter()
        self._c0 = self._c = time.process_time()
        self._th = time.thread_time()
        self._sw = runtime.Stopwatch()
        self.rows: list[dict] = []

    def __call__(self, name: str) -> None:
        t, c, th = time.perf_counter(), time.process_time(), time.thread_time()
        self.rows.append({"stage": name, "wall_s": round(t - self._t, 3),
                          "cpu_s": round(c - self._c, 3), "thread_cpu_s": round(th - self._th, 3),
                          "compile_s": self._sw.split()["compile_s"]})
        self._t, self._c, self._th, self._sw = t, c, th, runtime.Stopwatch()

    def add(self, name: str, wall_s: float, thread_cpu_s: float) -> None:
        """A stage timed in another thread (its own wall and thread CPU seconds)."""
        self.rows.append({"stage": name, "wall_s": round(wall_s, 3), "cpu_s": None,
                          "thread_cpu_s": round(thread_cpu_s, 3), "compile_s": None})

    def report(self) -> dict:
        """`{"stages": [...], "total": {"wall_s", "cpu_s"}}`."""
        return {"stages": list(self.rows),
                "total": {"wall_s": round(time.perf_counter() - self._t0, 3),
                          "cpu_s": round(time.process_time() - self._c0, 3)}}


def timed(fn, *args):
    """`(fn(*args), wall seconds, this thread's CPU seconds)`: a stage run in another thread."""
    t0, c0 = time.perf_counter(), time.thread_time()
    out = fn(*args)
    return out, time.perf_counter() - t0, time.thread_time() - c0


__all__ = ["Laps", "timed"]
