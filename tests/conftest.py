import os

os.environ.setdefault("MPLBACKEND", "Agg")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)


@pytest.fixture
def getkey():
    """Fresh, deterministic PRNG keys: `getkey()` returns the next key of a fixed sequence."""
    keys = iter(jax.random.split(jax.random.key(1234), 1000))
    return lambda: next(keys)
