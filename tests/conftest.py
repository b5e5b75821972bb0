import os

os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)

# Compiled code is shared across tests, xdist workers and runs through the persistent
# compilation cache (the same directory as the `jthermo` command: $JTHERMO_CACHE_DIR, else
# $XDG_CACHE_HOME/jthermo/jax, else ~/.cache/jthermo/jax; JTHERMO_NO_CACHE=1 switches it off).
# Set before the first compile: JAX opens the cache once per process.
from jthermo import runtime  # noqa: E402

runtime.enable_cache()


@pytest.fixture
def getkey():
    """Fresh, deterministic PRNG keys: `getkey()` returns the next key of a fixed sequence."""
    keys = iter(jax.random.split(jax.random.key(1234), 1000))
    return lambda: next(keys)
