"""Pieces the benchmarks and experiments share: CPU seconds and the machine's load, timed calls,
a cold child process, interleaved comparisons, where a script's results file lives, the head of
a Markdown results table, and a dense zero-order hold.

The dense hold is the form `mechanisms.zoh_blocks` replaced: the joint fit's benchmark times it,
and `tests/diagnose/test_mechanisms_zoh.py` (importing this module as `benchmarks.common`)
checks the blocks against it.

Scripts in `benchmarks/` import it as `common` (their own folder is first on `sys.path` when run
as `python benchmarks/x.py`); scripts in `experiments/` put `benchmarks/` on `sys.path` first:

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from common import cpu_seconds
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path


def results_path(script: str, suffix: str = ".md") -> Path:
    """The results file of `script` (its `__file__`): `<script's folder>/results/<script's
    name><suffix>`, the one file a rerun overwrites."""
    p = Path(script).resolve()
    return p.parent / "results" / (p.stem + suffix)


def cpu_seconds() -> float:
    """User + system CPU seconds of this process, all its threads (the load-robust figure on a
    shared machine, where wall seconds follow the load)."""
    t = os.times()
    return t.user + t.system


def load() -> str:
    """The 1-minute load average as text ("n/a" where /proc/loadavg cannot be read)."""
    try:
        return Path("/proc/loadavg").read_text().split()[0]
    except OSError:
        return "n/a"


def load1() -> float:
    """The 1-minute load average (NaN where /proc/loadavg cannot be read)."""
    try:
        return float(load())
    except ValueError:
        return float("nan")


def loads() -> str:
    """The 1-, 5- and 15-minute load averages as text ("n/a" where unreadable)."""
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def timed_call(fn):
    """`(fn(), wall s, CPU s)` of one call: CPU = user + system time of this process, all its
    threads (XLA's compiler threads included)."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def timed(fn):
    """`(fn(), wall s, CPU s)` of a second call (the first compiles), blocking on the result."""
    import jax

    jax.block_until_ready(fn())
    w, c = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(fn())
    return out, time.perf_counter() - w, time.process_time() - c


def cold_child(script: str, mode: str) -> tuple[str, dict]:
    """Run `python script --child mode` in a fresh process with an empty compilation cache
    (`JTHERMO_CACHE_DIR` a new temporary directory): (1-minute load at its start, the JSON its
    last stdout line holds)."""
    import json
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


def markdown_table_head(title: str, paragraphs: list[str], columns: list[str]) -> list[str]:
    """The first lines of a Markdown results file: `# title`, the paragraphs, and the header
    and separator rows of a table of `columns` (one separator cell per column)."""
    lines = [f"# {title}", ""]
    for p in paragraphs:
        lines += [p, ""]
    return lines + ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]


def compare_interleaved(cands: dict, reference, baseline: str = "numpy", repeats: int = 5) -> dict:
    """Print cold seconds and max abs error against `reference` for each zero-argument callable
    in `cands`, then the median and minimum warm seconds and the median of the per-repeat ratios
    `baseline seconds / candidate seconds`; returns the warm times `{name: [s, ...]}`. The
    candidates are repeated in turn, so that a drift of the machine's load hits them alike."""
    import jax
    import numpy as np

    for k, f in cands.items():
        t0 = time.perf_counter()
        out = jax.block_until_ready(f())
        err = float(np.max(np.abs(np.asarray(out) - reference)))
        print(k, "cold", round(time.perf_counter() - t0, 3), "err", err, flush=True)
    times = {k: [] for k in cands}
    for _ in range(repeats):
        for k, f in cands.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f())
            times[k].append(time.perf_counter() - t0)
    for k, v in times.items():
        ratio = statistics.median([n / t for n, t in zip(times[baseline], v)])
        print(k, "median", round(statistics.median(v), 4), "min", round(min(v), 4),
              f"x {baseline}", round(ratio, 2), flush=True)
    return times


# ---------------------------------------------------------------- the dense zero-order hold


def taylor_expm(Mt, squarings: int = 10, order: int = 10):
    """$e^{M}$ by the fixed Taylor series and squaring (branch-free) that
    `mechanisms.zoh_blocks` writes on blocks, here on the dense matrix."""
    import jax.numpy as jnp

    X = Mt / (2.0 ** squarings)
    eye = jnp.eye(Mt.shape[-1], dtype=Mt.dtype)
    term, out = eye, eye
    for k in range(1, order + 1):
        term = term @ X / k
        out = out + term
    for _ in range(squarings):
        out = out @ out
    return out


def zoh_dense(A, Bc, ts):
    """`(E, Bd, P1)` of `mechanisms.zoh_blocks` from the Taylor exponential of the dense
    $2m \\times 2m$ block matrix `[[A, I], [0, 0]] ts` (the form the blocks replaced)."""
    import jax.numpy as jnp

    m = A.shape[0]
    dt = A.dtype
    Mt = jnp.zeros((2 * m, 2 * m), dt).at[:m, :m].set(A).at[:m, m:].set(jnp.eye(m, dtype=dt))
    F = taylor_expm(Mt * ts)
    return F[:m, :m], F[:m, m:] @ Bc, F[:m, m:]
