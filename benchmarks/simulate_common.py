"""Pieces the benchmarks share: the 1-minute load, a cold child process, the Markdown ending."""

from __future__ import annotations

import time
from pathlib import Path


def load() -> str:
    """The 1-minute load average (2 shared cores: wall seconds follow it)."""
    return Path("/proc/loadavg").read_text().split()[0]


def cold_child(script: str, mode: str) -> tuple[str, dict]:
    """Run `python script --child mode` in a fresh process with an empty compilation cache
    (`JTHERMO_CACHE_DIR` a new temporary directory): (1-minute load at its start, the JSON its
    last stdout line holds)."""
    import json
    import os
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "JTHERMO_CACHE_DIR": cache}
        load0 = load()
        p = subprocess.run([sys.executable, script, "--child", mode], env=env,
                           capture_output=True, text=True, check=True)
    return load0, json.loads(p.stdout.strip().splitlines()[-1])


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
