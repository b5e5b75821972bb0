"""Pieces the `simulate_*` benchmarks share: the 1-minute load and the Markdown ending."""

from __future__ import annotations

import time
from pathlib import Path


def load() -> str:
    """The 1-minute load average (2 shared cores: wall seconds follow it)."""
    return Path("/proc/loadavg").read_text().split()[0]


def finish(lines: list[str], load0: str, out: str) -> None:
    """Close the report with the loads at the start and the end, print it, write it to `out`
    ('-': print only)."""
    lines += ["", f"1-minute load {load0} at the start, {load()} at the end."]
    text = "\n".join(lines) + "\n"
    print(text)
    if out != "-":
        Path(out).write_text(text)


def timed(fn):
    """`(fn(), wall s, CPU s)` of a second call (the first compiles), blocking on the result."""
    import jax

    jax.block_until_ready(fn())
    w, c = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - w, time.process_time() - c
