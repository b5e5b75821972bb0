"""Every tunable leaf of every controller: jax.grad of a closed-loop cost against central
differences in float64 (the loop stays away from saturation, where the cost is smooth)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from jthermo.control import design

from .loop import bed_plant, closed_loop, step_reference

T = 60


@pytest.fixture(scope="module")
def setup():
    plant = bed_plant(2, seed=3)
    r = step_reference(plant, T, 0.3, at=5)
    d = np.zeros((T, 2))
    d[40, 0] = -0.2
    return plant, r, jnp.asarray(d)


@pytest.mark.parametrize("family", ["pi_lambda", "pi_decoupled", "feedforward", "imc", "lqg",
                                    "gated_pi"])
def test_closed_loop_gradient(setup, family):
    plant, r, d = setup
    kwargs = {"kind": "ideal"} if family == "feedforward" else {}
    c = design(family, plant, **kwargs)
    params, static = eqx.partition(c, eqx.is_inexact_array)
    flat, unravel = ravel_pytree(params)

    @jax.jit
    def cost(theta):
        ctrl = eqx.combine(unravel(theta), static)
        ys, us = closed_loop(ctrl, plant, r, d)
        return jnp.mean((ys - r) ** 2) + 0.1 * jnp.mean((us - plant.u0) ** 2)

    g = np.asarray(jax.grad(cost)(flat))
    # leaves the controller holds fixed (its internal model, operating point) have zero
    # gradient by design (stop_gradient): compare on the parameters the cost depends on
    free = np.flatnonzero(np.abs(g) > 0)
    assert free.size >= 2
    x = np.asarray(flat)
    g_fd = np.empty(free.size)
    for j, i in enumerate(free):
        h = np.sqrt(np.finfo(np.float64).eps) * max(1.0, abs(x[i]))
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        g_fd[j] = (float(cost(jnp.asarray(xp))) - float(cost(jnp.asarray(xm)))) / (2 * h)
    np.testing.assert_allclose(g[free], g_fd, rtol=2e-4, atol=1e-8)
