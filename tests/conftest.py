import gc
import os

os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)

# Compiled code is shared across tests, xdist workers and runs through the persistent
# compilation cache: $JTHERMO_CACHE_DIR when set, else a `jax-tests` directory beside the
# command's own cache ($XDG_CACHE_HOME/jthermo/jax-tests, else ~/.cache/jthermo/jax-tests), so
# the suite's ~10^4 entries do not slow the user's cache (JAX scans every entry of a bounded
# cache on each write); JTHERMO_NO_CACHE=1 switches it off. Set before the first compile: JAX
# opens the cache once per process.
from jthermo import runtime  # noqa: E402

runtime.enable_cache(None if os.environ.get(runtime.ENV_DIR)
                     else runtime.default_cache_dir().with_name("jax-tests"))
runtime.one_matrix_at_a_time()   # as the command does: no LAPACK kernel waits on XLA's pool
# programs this process compiles (or loads from the persistent cache), reported at the end
runtime.count_compiles()


@pytest.fixture
def getkey():
    """Fresh, deterministic PRNG keys: `getkey()` returns the next key of a fixed sequence."""
    keys = iter(jax.random.split(jax.random.key(1234), 1000))
    return lambda: next(keys)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drop a test module's compiled programs when it ends (a later module that needs one
    loads it from the persistent cache). Every XLA CPU executable keeps memory maps of its
    code, and an xdist worker that held the programs of all its modules neared Linux's
    per-process limit (`vm.max_map_count`, 65530), where a worker segfaulted in the unwinder
    or LLVM failed with "Cannot allocate memory". Cleared after each module, a process keeps a
    small fraction of the maps and about half the peak memory, in no more time (measured by
    `python benchmarks/memory_maps_tests.py`)."""
    yield
    if not os.environ.get("JTHERMO_TESTS_KEEP_COMPILED"):    # benchmarks/memory_maps_tests.py
        jax.clear_caches()
        gc.collect()


def pytest_sessionfinish(session):
    """An xdist worker hands its compiled-program count to the controller."""
    out = getattr(session.config, "workeroutput", None)
    if out is not None:
        out["jthermo_compiled"] = runtime.compiled_programs()
        out["jthermo_clears"] = runtime.guard_info()["clears"]


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    out = getattr(node, "workeroutput", None) or {}
    counts = node.config.stash.setdefault(_WORKER_COUNTS, [])
    counts.append((out.get("jthermo_compiled", 0), out.get("jthermo_clears", 0)))


_WORKER_COUNTS = pytest.StashKey[list]()


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """The programs the suite compiled (or loaded from the persistent cache), all processes."""
    workers = config.stash.get(_WORKER_COUNTS, [])
    compiled = runtime.compiled_programs() + sum(c for c, _ in workers)
    clears = runtime.guard_info()["clears"] + sum(k for _, k in workers)
    terminalreporter.write_line(
        f"jthermo: {compiled} programs compiled or loaded in {max(len(workers), 1)} "
        f"process(es); memory-map guard cleared {clears} time(s)")
