"""`runtime.unroll_threefry`: the same random bits as JAX's CPU lowering, without its loop."""

import subprocess
import sys

import numpy as np

CHILD = """
import sys
import jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
from jthermo import runtime
if sys.argv[1] == "1":
    assert runtime.unroll_threefry()
f = jax.jit(lambda k: jax.vmap(lambda kk: jax.random.normal(kk, (50, 3), jnp.float64))(
    jax.random.split(k, 4)))
text = f.lower(jax.random.key(7)).compile().as_text()
sys.stdout.write(repr(" while(" in text) + "\\n")
sys.stdout.write(" ".join(map(repr, f(jax.random.key(7)).ravel().tolist())))
"""


def _draw(unrolled: bool):
    # a fresh process each: the lowering is process-wide, and the suite keeps JAX's default
    out = subprocess.run([sys.executable, "-c", CHILD, "1" if unrolled else "0"], check=True,
                         capture_output=True, text=True, env={"JTHERMO_NO_CACHE": "1",
                                                               "PATH": ""}).stdout.splitlines()
    return out[0] == "True", np.array([float(v) for v in out[1].split()])


def test_unrolled_threefry_draws_the_same_bits_without_a_loop():
    loop_default, default = _draw(False)
    loop_unrolled, unrolled = _draw(True)
    assert loop_default and not loop_unrolled
    np.testing.assert_array_equal(default, unrolled)
