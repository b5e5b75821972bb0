import equinox as eqx
import jax.numpy as jnp
import numpy as np


def tree_allclose(x, y, *, rtol=1e-5, atol=1e-8):
    return eqx.tree_equal(x, y, typematch=True, rtol=rtol, atol=atol)


def central_difference(f, x, eps=None):
    """Central finite-difference gradient of scalar `f` at flat float64 array `x`."""
    x = np.asarray(x, dtype=np.float64)
    g = np.zeros_like(x)
    for i in range(x.size):
        h = (eps if eps is not None else np.sqrt(np.finfo(np.float64).eps) * max(1.0, abs(x.flat[i])))
        xp = x.copy(); xp.flat[i] += h
        xm = x.copy(); xm.flat[i] -= h
        g.flat[i] = (float(f(jnp.asarray(xp))) - float(f(jnp.asarray(xm)))) / (2 * h)
    return g
