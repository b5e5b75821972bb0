"""JAX runtime settings of the application: the persistent compilation cache, and the split
of a run's wall time into compiling and running.

Importing this module changes nothing: the library never touches JAX's global configuration
by itself. The `jthermo` command calls `enable_cache()` before it compiles anything; scripts,
experiments and the test suite may call it too.

**The cache.** XLA executables are written to a directory, keyed by a hash of the compiled
program, the JAX/XLA version and the flags, so a second process loads what the first one
compiled instead of compiling it again (JAX's persistent compilation cache). The directory is
`$JTHERMO_CACHE_DIR`, else `$XDG_CACHE_HOME/jthermo/jax`, else `~/.cache/jthermo/jax`;
`JTHERMO_NO_CACHE=1` (or `jthermo --no-cache`) switches it off. Every compile is cached, however
small: jthermo's closed loops, fits and tests compile hundreds of small programs, and loading
one from disk costs milliseconds (`benchmarks/latency.py` measures what that buys).

**Concurrent processes.** The cache is given a size bound, which makes JAX guard each read and
write with a file lock (`filelock`); a partly written entry is never read. An entry that cannot
be read or written (a lock timeout, a full disk) makes JAX compile as if it were absent.
A directory that cannot be created or written (a read-only home) turns the cache off for the
process: the command runs as without it.

**LAPACK on the CPU, one matrix at a time.** `one_matrix_at_a_time()` lowers every batched
factorisation or solve to a loop over single matrices, so that no LAPACK kernel waits on XLA's
CPU thread pool: two programs running at once (threads) can then never deadlock there. The
command, the test suite and every library function that runs programs on two threads switch it
on (`python experiments/printer_scale.py --ab` compares it with running `tune_report`'s two
threads' work one after the other).

**Compiled programs.** `guard`, called where the library's fits, diagnoses and sweep trials
start, drops the process's compiled programs (JAX's caches, `program_factory`'s) once its
memory maps reach `map_bound()`: a long-lived process never nears Linux's limit. They live in
`jthermo.programs`, with `top_level` (is the caller outside every JAX trace?), and are
re-exported here.

**Timing.** `Stopwatch` listens to JAX's monitoring events for tracing, lowering and backend
compilation and sums the union of their time spans (nested traces count once); `run_s` is the
rest of the wall time.
"""

from __future__ import annotations

import functools
import os
import tempfile
import threading
import time
from pathlib import Path

from .programs import (  # noqa: F401  (re-exported: the library calls `runtime.guard()`)
    clear_programs,
    compiled_programs,
    count_compiles,
    guard,
    guard_info,
    map_bound,
    memory_maps,
    program_factory,
    top_level,
)

ENV_DIR = "JTHERMO_CACHE_DIR"
ENV_OFF = "JTHERMO_NO_CACHE"

#: Cache every compile, however short: the default (1 s) skips almost all of jthermo's.
MIN_COMPILE_SECONDS = 0.0
#: Bound of the cache directory; least recently used entries are evicted beyond it. A bound is
#: what makes JAX lock the directory during reads and writes (safe between processes); its
#: price is that JAX scans every entry on each write, so a write costs time in proportion to the
#: number of entries (the test suite keeps its own directory, `tests/conftest.py`).
MAX_CACHE_BYTES = 4 * 1024**3

#: XLA options for a program a process runs once, on small arrays (the printer's design point):
#: LLVM at -O0 and XLA's older (non-MLIR) CPU fusion emitters compile it in a fraction of the
#: CPU time (measured by `python benchmarks/one_shot_compile.py`),
#: and its run time is negligible either way. Never for a program inside a loop: -O0 code runs
#: several times slower.
ONE_SHOT = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
#: XLA options for a program compiled once per cache and run once per command (`jthermo
#: simulate`'s run program): XLA's older CPU fusion emitters compile it in less time than they
#: cost in run time, with the same figures bit for bit (measured at N = 16, B = 256, T = 3600 by
#: `python benchmarks/simulate_compile_options.py`)
QUICK_COMPILE = {"xla_cpu_use_fusion_emitters": False}
#: XLA options for `jthermo simulate`'s run program: `QUICK_COMPILE` with LLVM at -O1: a
#: shorter compile and no slower execution, mse equal to 1e-16 relative (measured by
#: `python benchmarks/simulate_compile_options.py`)
SIMULATE_COMPILE = {**QUICK_COMPILE, "xla_backend_optimization_level": 1}
#: the options above that an XLA lacking them refuses ("No such compile option")
NEWER_OPTIONS = ("xla_cpu_use_fusion_emitters",)

#: JAX's monitoring events that time compilation (jax/_src/dispatch.py).
COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration",
                  "/jax/core/compile/jaxpr_to_mlir_module_duration",
                  "/jax/core/compile/backend_compile_duration")

#: the process's compilation cache: its directory (`dir`, None when off) and why it is off
#: (`reason`); `threefry` once `unroll_threefry` swapped the lowering, `lapack` once
#: `one_matrix_at_a_time` did, `looped` the batched LAPACK calls it has lowered to loops
state: dict = {"dir": None, "reason": "not enabled"}
_spans: list[tuple[float, float]] = []
_lock = threading.Lock()
_install_lock = threading.Lock()
_listening = False


def _off(value: str | None) -> bool:
    return (value or "").strip().lower() not in ("", "0", "false", "no", "off")


def default_cache_dir() -> Path:
    """Where the cache lives: `$JTHERMO_CACHE_DIR`, else `$XDG_CACHE_HOME/jthermo/jax`, else
    `~/.cache/jthermo/jax`."""
    explicit = os.environ.get(ENV_DIR)
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path("~/.cache").expanduser()
    return base / "jthermo" / "jax"


def _writable(path: Path) -> str | None:
    """None when `path` can be created and written into, else the reason it cannot."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".probe-", dir=path)
        os.close(fd)
        os.unlink(probe)
    except (OSError, ValueError) as exc:  # ValueError: a path with a NUL byte
        return f"{path}: {getattr(exc, 'strerror', None) or exc}"
    return None


def enable_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Switch on JAX's persistent compilation cache for this process and its children.

    **Arguments:**

    - `path`: the cache directory; default `default_cache_dir()`.

    **Returns:** the directory in use, or None when the cache stays off (`JTHERMO_NO_CACHE`
    set, or the directory cannot be written: `cache_info()` says why). Never raises.
    Call it before the first compile: JAX opens the cache once per process.
    """
    if _off(os.environ.get(ENV_OFF)):
        disable_cache(f"{ENV_OFF} is set")
        return None
    target = Path(path).expanduser() if path is not None else default_cache_dir()
    reason = _writable(target)
    if reason is not None:
        disable_cache(f"cannot write {reason}")
        return None
    import jax

    try:
        import filelock  # noqa: F401  (JAX locks the directory with it when a bound is set)

        bound = MAX_CACHE_BYTES
    except ImportError:
        bound = -1  # unbounded, unlocked: entries are zlib streams, a torn read is rejected
    settings = {"jax_enable_compilation_cache": True, "jax_compilation_cache_dir": str(target),
                "jax_persistent_cache_min_compile_time_secs": MIN_COMPILE_SECONDS,
                "jax_persistent_cache_min_entry_size_bytes": -1,
                "jax_compilation_cache_max_size": bound}
    for name, value in settings.items():
        jax.config.update(name, value)
        # worker processes (sweeps) inherit the cache
        os.environ[name.upper()] = str(value).lower() if isinstance(value, bool) else str(value)
    state.update(dir=target, reason=None)
    return target


def disable_cache(reason: str = "disabled") -> None:
    """Keep the cache off in this process and its children (`jthermo --no-cache`), even where
    the environment names a JAX cache directory."""
    import jax

    jax.config.update("jax_enable_compilation_cache", False)
    os.environ["JAX_ENABLE_COMPILATION_CACHE"] = "false"
    os.environ[ENV_OFF] = "1"
    state.update(dir=None, reason=reason)


def cache_info() -> str:
    """One line: the cache directory in use and its entry count, or why there is none."""
    d = state["dir"]
    if d is None:
        return f"compilation cache off ({state['reason']})"
    try:
        n = sum(1 for p in Path(d).iterdir() if p.name.endswith("-cache"))
    except OSError:
        n = 0
    return f"compilation cache {d} ({n} entries)"


def one_shot() -> dict:
    """`ONE_SHOT` as this XLA accepts it, for `compiler_options=` (`accepted`)."""
    return accepted(ONE_SHOT)


def quick_compile() -> dict:
    """`QUICK_COMPILE` as this XLA accepts it, for `compiler_options=` (`accepted`)."""
    return accepted(QUICK_COMPILE)


def simulate_compile() -> dict:
    """`SIMULATE_COMPILE` as this XLA accepts it, for `compiler_options=` (`accepted`)."""
    return accepted(SIMULATE_COMPILE)


def accepted(options: dict) -> dict:
    """`options` less those of `NEWER_OPTIONS` this XLA refuses: probed once per process and
    option set on a scalar program, so an XLA without its older CPU fusion emitters (a future
    one, or one predating the flag) compiles with the rest rather than failing."""
    return dict(accepted_items(tuple(options.items())))


@functools.cache
def accepted_items(items: tuple) -> tuple:
    import jax
    import numpy as np

    try:   # evaluated now even when the first caller is inside a trace
        with jax.ensure_compile_time_eval():
            out = jax.jit(lambda x: x + 1, compiler_options=dict(items))(np.float32(1))
        jax.block_until_ready(out)
        return items
    except Exception:  # noqa: BLE001  (JaxRuntimeError: INVALID_ARGUMENT, no such option)
        return tuple((k, v) for k, v in items if k not in NEWER_OPTIONS)


# ---------------------------------------------------------------- random bits on the CPU


def unroll_threefry() -> bool:
    """Lower JAX's Threefry-2x32 hash on the CPU with its five rounds unrolled (the lowering JAX
    uses on GPUs) instead of a `while` loop over the whole arrays: the same bits, every
    random draw the same. On `jthermo simulate`'s run program (N = 16, B = 256, T = 3600) it
    compiles in less time, runs in the same time and lowers the command's peak memory
    (measured by `python benchmarks/simulate_threefry.py`).

    Changes the lowering of every program compiled afterwards in this process (their cache
    keys too), so the command calls it once at start-up, as it does `enable_cache`. Returns
    False, changing nothing, where this JAX lacks the lowering rule it swaps in."""
    try:
        from jax._src.interpreters import mlir
        from jax._src.random import threefry2x32 as tf

        rule, prim = tf._threefry2x32_lowering_rule, tf.threefry2x32_p
    except (ImportError, AttributeError):
        return False
    mlir.register_lowering(prim, rule, platform="cpu")
    state["threefry"] = "unrolled"   # part of `stored.exported_call`'s key
    return True


# ---------------------------------------------------------------- LAPACK, one matrix at a time


#: the CPU-lowered LAPACK primitives of `jax._src.lax.linalg` and the core rank of each
#: operand (the dimensions before it are batch dimensions)
_LAPACK_RANKS = {"cholesky_p": (2,), "eig_p": (2,), "eigh_p": (2,), "geqp3_p": (2, 1),
                 "geqrf_p": (2,), "hessenberg_p": (2,), "householder_product_p": (2, 1),
                 "lu_p": (2,), "ormqr_p": (2, 1, 2), "schur_p": (2,), "svd_p": (2,),
                 "triangular_solve_p": (2, 2), "tridiagonal_p": (2,),
                 "tridiagonal_solve_p": (1, 1, 1, 2)}


def one_matrix_at_a_time() -> bool:
    """Lower every LAPACK call on the CPU with batch dimensions (a factorisation or solve
    under `jax.vmap`, or of a stack of matrices) to a loop (`lax.map`) over single matrices.

    Why: jaxlib's CPU LAPACK kernels (LU, triangular solve, Cholesky, QR, eig, eigh, SVD,
    Schur, ...) deal a batch whose work exceeds 2e5 flops to XLA's intra-op thread pool in
    chunks and block the pool thread they run on until the chunks are done
    (`ParallelBatchMap` in jaxlib 0.10's `cpu/lapack_kernels.cc`). Two such kernels running
    at once, from two programs on two Python threads or from two independent operations of
    one program, hold both threads of a two-thread pool (two cores) and wait for good: the
    hang of `jthermo tune --plant printer --zones 16` (gdb: both `tf_XLAEigen` threads in
    `LuDecomposition::Kernel` -> `ParallelBatchMap` -> `BlockingCounter::Wait`), as of the
    diagnosis's split fits before (`identify/lm.py`). A kernel given one matrix runs it in
    its own thread and never schedules onto the pool, so no factorisation can wait on the
    pool whatever runs beside it: deadlock-free by construction, for every caller, not only
    the call sites known today. Same results: each matrix goes through the same LAPACK
    routine; transformations (grad, vmap) are unaffected (the rule acts at lowering).

    Changes the lowering of every program compiled afterwards in this process (and the keys
    of `stored.exported_call`, `lowering_tags`); on first use it empties JAX's in-memory
    caches, so that no program compiled before (with a batched kernel) runs again. Idempotent
    and cheap after the first call: the CLI calls it at start-up, and every library function
    that runs compiled programs on more than one thread calls it before it starts them.
    Returns False, changing nothing, where this JAX lacks the internals it relies on."""
    if state.get("lapack") == "one matrix at a time":
        return True
    with _install_lock:
        if state.get("lapack") == "one matrix at a time":
            return True
        try:
            from jax._src.interpreters import mlir
            from jax._src.lax import linalg

            cpu = mlir._platform_specific_lowerings["cpu"]
            rules = {getattr(linalg, name): (ranks, cpu[getattr(linalg, name)].rule)
                     for name, ranks in _LAPACK_RANKS.items()
                     if getattr(linalg, name, None) in cpu}
        except (ImportError, AttributeError, KeyError):
            return False
        for prim, (ranks, rule) in rules.items():
            mlir.register_lowering(prim, _looped_lowering(prim, ranks, rule), platform="cpu")
        state["lapack"] = "one matrix at a time"
    import jax

    jax.clear_caches()   # nothing compiled before the rule runs again
    return True


def _looped_lowering(prim, ranks, rule):
    """The CPU lowering of `prim`: `rule` itself for an unbatched call, else a `lax.map` of
    `prim` over the flattened batch (each inner call lowers through `rule`, one matrix)."""
    import math

    import jax

    from jax._src.interpreters import mlir

    def lower(ctx, *args, **params):
        shape0 = ctx.avals_in[0].shape
        batch = tuple(shape0[:len(shape0) - ranks[0]])
        count = math.prod(batch)
        if count <= 1 or not all(isinstance(d, int) for d in batch):
            return rule(ctx, *args, **params)
        state["looped"] = state.get("looped", 0) + 1

        def looped(*ops):
            flat = [o.reshape((count, *o.shape[len(batch):])) for o in ops]
            out = jax.lax.map(lambda xs: prim.bind(*xs, **params), flat)
            outs = out if prim.multiple_results else [out]
            outs = [o.reshape((*batch, *o.shape[1:])) for o in outs]
            return outs if prim.multiple_results else outs[0]

        return mlir.lower_fun(looped, multiple_results=prim.multiple_results)(ctx, *args)

    return lower


def looped_calls() -> int:
    """How many batched LAPACK calls `one_matrix_at_a_time` has lowered to a loop so far in
    this process (a lowering loaded from the persistent cache is not counted)."""
    return int(state.get("looped", 0))


def lowering_tags() -> str:
    """The lowering swaps of this process (`unroll_threefry`, `one_matrix_at_a_time`), as
    one string: part of `stored.exported_call`'s key."""
    return f"threefry={state.get('threefry')} lapack={state.get('lapack')}"


# ---------------------------------------------------------------- the CPU backend's threads


#: the most schedulable CPUs for which `one_thread_backend` acts (measured on 2 cores only)
ONE_THREAD_MAX_CPUS = 2


#: 1-minute load average, per schedulable CPU beyond the first, from which a machine counts
#: as busy (`busy`): on an idle machine two threads run `jthermo simulate` slightly faster in
#: wall time for more CPU time, on a busy one a single thread is faster
BUSY_LOAD_PER_CPU = 1.0


def busy() -> bool:
    """True where the 1-minute load average leaves no CPU spare for a second intra-op thread:
    `load >= BUSY_LOAD_PER_CPU * (cpus - 1)`; True where it cannot be read."""
    try:
        load = os.getloadavg()[0]
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return True
    return load >= BUSY_LOAD_PER_CPU * max(cpus - 1, 1)


def one_thread_backend() -> bool:
    """Create JAX's CPU backend with one intra-op thread: XLA sizes its thread pool by the
    CPUs the process may use, so the calling thread is pinned to one CPU while the backend is
    made, then every thread of the process is given all its CPUs back. `jthermo simulate`'s
    programs are loops of small operations (B x n = 256 x 33) that a second thread only
    slows: on 2 shared cores both the run program and its first call (trace, compile, run)
    take less CPU time with one thread, the same figures bit for bit.

    Returns False, changing nothing, where the backend exists already, the platform cannot
    set CPU affinities, or the process may use more than `ONE_THREAD_MAX_CPUS` CPUs."""
    import jax

    try:
        from jax._src import xla_bridge

        if xla_bridge.backends_are_initialized():
            return False
        cpus = os.sched_getaffinity(0)
    except (ImportError, AttributeError, OSError):
        return False
    if not 1 < len(cpus) <= ONE_THREAD_MAX_CPUS:
        return False
    try:
        os.sched_setaffinity(0, {min(cpus)})
        jax.devices()
    finally:
        _unpin(cpus)
    return True


def _unpin(cpus) -> None:
    """Every thread of this process may run on `cpus` again."""
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    for tid in tids:
        try:
            os.sched_setaffinity(tid, cpus)
        except OSError:   # a thread that ended meanwhile
            pass


# ---------------------------------------------------------------- compile-time accounting


def _on_span(event: str, start: float, end: float, **_) -> None:
    if event in COMPILE_EVENTS:
        with _lock:
            _spans.append((start, end))


def _listen() -> None:
    global _listening
    with _lock:
        if _listening:
            return
        _listening = True
    import jax.monitoring

    jax.monitoring.register_event_time_span_listener(_on_span)


def union_seconds(spans, lo: float, hi: float) -> float:
    """Length of the union of the intervals `spans`, clipped to `[lo, hi]`."""
    total, reach = 0.0, lo
    for a, b in sorted(spans):
        a, b = max(a, reach), min(b, hi)
        if b > a:
            total += b - a
            reach = b
    return total


class Stopwatch:
    """Wall time since construction, split into compile and run seconds.

    Compile time is the union of the time spans of JAX's tracing, lowering and backend
    compile events (a cache hit counts as its short load); `run_s` is the rest.
    """

    def __init__(self):
        _listen()
        self.start = time.time()

    def split(self) -> dict[str, float]:
        """`{"seconds": total, "compile_s": ..., "run_s": ...}` so far, rounded to 1 ms."""
        now = time.time()
        with _lock:
            spans = list(_spans)
        compile_s = union_seconds(spans, self.start, now)
        total = now - self.start
        return {"seconds": round(total, 3), "compile_s": round(compile_s, 3),
                "run_s": round(max(total - compile_s, 0.0), 3)}


def cache_dir() -> Path | None:
    """This process's cache directory, None with the cache off (`enable_cache`)."""
    return state["dir"]


def threefry_lowering() -> str | None:
    """"unrolled" once `unroll_threefry` swapped the CPU lowering in, else None."""
    return state.get("threefry")
