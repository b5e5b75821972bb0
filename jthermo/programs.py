"""The process's compiled programs: one bounded cache of program factories, and a guard on
memory maps.

**Why a guard.** Every XLA CPU executable keeps memory maps of its code; past
`vm.max_map_count` (65,530 by default) LLVM aborts the process with no Python exception, and
a process that fits records of many lengths and zone counts (a notebook, a study, a sweep
worker) compiles a program per shape. `guard`, called where the library's fits, diagnoses and
sweep trials start, drops the process's compiled programs (JAX's caches, `program_factory`'s)
once its memory maps reach `map_bound()`; nothing is lost but time, a program needed again is
traced again and compiled, or loaded from the persistent cache (`runtime.enable_cache`).

`runtime` re-exports the functions below (the library calls `runtime.guard()`); the settings
`MAP_BOUND` and `FACTORY_CACHE_SIZE` are read here, so a script or a test changes them on this
module.
"""

from __future__ import annotations

import functools
import gc
import threading
from pathlib import Path

#: memory maps at which `guard` drops the process's compiled programs (or a third of the
#: system's limit if lower, `map_bound`). What one job adds between two guards (a state-space fit ~1,300, a generated record ~300:
#: `python benchmarks/memory_maps.py`) then leaves a process well below 30,000.
MAP_BOUND = 20_000
#: entries of the library's one cache of program factories (`program_factory`)
FACTORY_CACHE_SIZE = 64
#: JAX's duration event of a program made, once a program: it times the backend compile and,
#: on a hit, the read from the persistent cache (JAX's `cache_retrieval_time_sec` event, inside
#: it, is not counted again)
_PROGRAM_EVENTS = ("/jax/core/compile/backend_compile_duration",)

_guard = {"compiled": 0, "checked_at": -1, "clears": 0, "maps": None, "listening": False}
_factories: dict[tuple, object] = {}   # an LRU: insertion order, most recent last
_factory_lock = threading.Lock()


def top_level() -> bool:
    """True outside every JAX trace (jit, grad, vmap): only there may a program compiled with
    its own `compiler_options` be called (JAX refuses them on a nested jit). False where this
    JAX lacks the check (then such callers take their plain jit)."""
    try:
        from jax._src.core import trace_state_clean
    except ImportError:
        return False
    return bool(trace_state_clean())


def _on_duration(event: str, duration: float, **_) -> None:
    if event in _PROGRAM_EVENTS:
        _guard["compiled"] += 1


def count_compiles() -> None:
    """Count the programs this process compiles or loads from the persistent cache from now on."""
    with _factory_lock:
        if _guard["listening"]:
            return
        _guard["listening"] = True
    import jax.monitoring

    jax.monitoring.register_event_duration_secs_listener(_on_duration)


def compiled_programs() -> int:
    """Programs compiled (or loaded) since `count_compiles` was first called."""
    return _guard["compiled"]


def memory_maps() -> int | None:
    """The process's memory maps (lines of `/proc/self/maps`); None where there are none."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return None


@functools.cache
def map_bound() -> int:
    """`MAP_BOUND`, or a third of `/proc/sys/vm/max_map_count` where that is lower."""
    try:
        limit = int(Path("/proc/sys/vm/max_map_count").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return MAP_BOUND
    return min(MAP_BOUND, max(limit // 3, 1))


def program_factory(fn):
    """Decorator: `fn(*key)` (a function that builds a compiled program, e.g. returns an
    `eqx.filter_jit`) memoised in the library's one cache of program factories, bounded to
    `FACTORY_CACHE_SIZE` entries over all factories (least recently used dropped first) and
    emptied by `clear_programs` (or, for `fn`'s entries, `cache_clear`). Arguments must be
    hashable (as for `functools.cache`)."""
    name = (fn.__module__, fn.__qualname__)

    @functools.wraps(fn)
    def get(*args):
        key = name + args
        with _factory_lock:
            if key in _factories:
                _factories[key] = _factories.pop(key)
                return _factories[key]
        value = fn(*args)
        with _factory_lock:
            _factories[key] = value
            while len(_factories) > FACTORY_CACHE_SIZE:
                _factories.pop(next(iter(_factories)))
        return value

    def cache_clear():
        with _factory_lock:
            for key in [k for k in _factories if k[:2] == name]:
                del _factories[key]

    get.cache_clear = cache_clear
    return get


def clear_programs() -> None:
    """Drop every compiled program of the process: JAX's caches (`jax.clear_caches`) and the
    library's program factories. Nothing is lost but time: a program needed again is traced
    again and compiled, or loaded from the persistent cache (`enable_cache`)."""
    import jax

    with _factory_lock:
        _factories.clear()
    jax.clear_caches()
    gc.collect()


def guard() -> bool:
    """Keep the process below `map_bound()` memory maps: where programs were compiled since
    the last look and the maps reach the bound, `clear_programs()` (never inside a trace).
    Called where fits, diagnoses and sweep trials start: a long-lived process (a notebook, a
    study, a sweep worker) needs no cache clearing of its own. One read of `/proc/self/maps`
    after a compile, none otherwise. True when it cleared."""
    count_compiles()
    if _guard["compiled"] == _guard["checked_at"] or not top_level():
        return False
    _guard["checked_at"] = _guard["compiled"]
    n = _guard["maps"] = memory_maps()
    if n is not None and n >= map_bound():
        clear_programs()
        _guard["clears"] += 1
        _guard["maps"] = memory_maps()
        return True
    return False


def guard_info() -> dict:
    """`{"bound", "clears", "maps" (at the last look), "compiled"}` of this process's guard."""
    return {"bound": map_bound(), "clears": _guard["clears"], "maps": _guard["maps"],
            "compiled": _guard["compiled"]}
