"""The process guards its compiled programs (`jthermo.programs`, re-exported by `runtime`):
one bounded factory cache, a memory-map guard."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo import programs, runtime


def test_runtime_reexports_the_guard():
    """The library calls `runtime.guard()`: runtime's names are the programs module's own."""
    for name in ("guard", "guard_info", "count_compiles", "compiled_programs", "memory_maps",
                 "map_bound", "program_factory", "clear_programs", "top_level"):
        assert getattr(runtime, name) is getattr(programs, name), name


def test_memory_maps_counts_proc_self_maps():
    with open("/proc/self/maps", "rb") as f:
        n = sum(1 for _ in f)
    m = runtime.memory_maps()
    assert m is not None and abs(m - n) < 50


def test_map_bound_below_the_system_limit():
    with open("/proc/sys/vm/max_map_count") as f:
        limit = int(f.read())
    assert 0 < programs.map_bound() <= min(programs.MAP_BOUND, limit // 3)


def test_program_factory_is_one_bounded_lru(monkeypatch):
    monkeypatch.setattr(programs, "FACTORY_CACHE_SIZE", 3)
    calls = []

    @runtime.program_factory
    def make(n):
        calls.append(n)
        return jax.jit(lambda x: x * n)

    @runtime.program_factory
    def other(n):
        calls.append(-n)
        return object()

    f1 = make(1)
    assert make(1) is f1 and calls == [1]
    make(2), other(1)
    make(1)                                    # 1 most recently used: 2 is the oldest now
    make(3)                                    # over the bound of 3: drops make(2)
    assert calls == [1, 2, -1, 3]
    make(1), other(1)
    assert calls == [1, 2, -1, 3]              # kept
    make(2)
    assert calls[-1] == 2                      # rebuilt
    make.cache_clear()
    make(1)
    assert calls[-1] == 1
    other(1)
    assert calls[-1] == 1                      # the other factory's entries survive its clear
    runtime.clear_programs()
    other(1)
    assert calls[-1] == -1


def test_guard_clears_at_the_bound(monkeypatch):
    f = jax.jit(lambda x: jnp.cumsum(x) * 2.0)
    runtime.count_compiles()
    for n in (3, 4, 5):
        f(np.ones(n))
    assert f._cache_size() == 3
    monkeypatch.setattr(programs, "map_bound", lambda: 10 ** 9)
    assert runtime.guard() is False            # below the bound: nothing dropped
    assert f._cache_size() == 3
    clears = runtime.guard_info()["clears"]
    monkeypatch.setattr(programs, "map_bound", lambda: 1)
    assert runtime.guard() is False            # no compile since the last look: no read
    f(np.ones(6))
    assert runtime.guard() is True
    assert f._cache_size() == 0
    assert runtime.guard_info()["clears"] == clears + 1
    np.testing.assert_allclose(f(np.ones(3)), [2.0, 4.0, 6.0])   # compiled again when needed


def test_guard_never_clears_inside_a_trace(monkeypatch):
    monkeypatch.setattr(programs, "map_bound", lambda: 1)
    seen = []

    @jax.jit
    def g(x):
        seen.append(runtime.guard())
        return x + 1

    g(np.ones(7))
    assert seen == [False]


def test_fit_entry_runs_the_guard(monkeypatch):
    from jthermo.data import from_arrays
    from jthermo.identify.fit import fit

    calls = []
    monkeypatch.setattr(runtime, "guard", lambda: calls.append(1) or False)
    rng = np.random.default_rng(0)
    u = rng.uniform(0, 1, (200, 1))
    y = np.convolve(u[:, 0], 0.5 ** np.arange(20))[:200, None] + 0.01 * rng.standard_normal((200, 1))
    fit(from_arrays(u, y, 1.0), "arx", (1, 1, 1))
    assert calls


def test_diagnose_runs_the_guard_between_its_stages(monkeypatch):
    """A diagnosis compiles ~3,500 maps of programs: the guard runs at its start and after each
    stage, before the stage is reported."""
    from jthermo.diagnose import diagnose
    from tests.diagnose.records import record

    calls, seen = [], []
    monkeypatch.setattr(runtime, "guard", lambda: calls.append(1) or False)
    est, val = record(None, 0)          # the canonical records (tests/diagnose/records.py)
    diagnose(est, val, progress=lambda i, n, info: seen.append((i, len(calls))))
    assert [i for i, _ in seen] == [1, 2, 3, 4, 5, 6]
    assert [c for _, c in seen] == sorted(c for _, c in seen) and seen[0][1] >= 2
    assert all(b > a for (_, a), (_, b) in zip(seen, seen[1:]))


COUNT_CHILD = """
import sys, jax, jax.monitoring, jax.numpy as jnp
from jthermo import runtime
reads = []
jax.monitoring.register_event_duration_secs_listener(
    lambda e, d, **_: reads.append(e) if e == "/jax/compilation_cache/cache_retrieval_time_sec" else None)
runtime.enable_cache(sys.argv[1])
runtime.count_compiles()
f = jax.jit(lambda x: jnp.sin(x) * 3.0 + x ** 2)
f(jnp.arange(5.0)).block_until_ready()
print(runtime.compiled_programs(), len(reads))
"""


def test_a_program_read_from_the_persistent_cache_counts_once(tmp_path):
    """A program is counted when it is made, compiled (first process) or read from the
    persistent cache (second process): once each, not once more for the read."""
    import subprocess
    import sys

    runs = [[int(v) for v in subprocess.run([sys.executable, "-c", COUNT_CHILD, str(tmp_path)],
                                            capture_output=True, text=True, check=True).stdout.split()[-2:]]
            for _ in range(2)]
    (made_first, reads_first), (made_second, reads_second) = runs
    assert reads_first == 0 and reads_second >= 1      # the second process did read from the cache
    assert made_first == made_second >= 1
