"""The smooth peak sensitivity inside the tuning cost (`tune.sensitivity`): it bounds
`control.margins.peak_sensitivity` on the same grid from above within t·log F, its penalty's
gradient matches central differences, and it vanishes inside the limit."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from jthermo.control import design
from jthermo.control.margins import peak_sensitivity
from jthermo.control.mimo_pi import MIMOPI
from jthermo.tune.sensitivity import model_response, ms_penalty, soft_peak_sensitivity
from tests.control.loop import bed_plant
from tests.helpers import central_difference


def _loops():
    plant = bed_plant(2, seed=1)
    pi = design("pi_lambda", plant)
    sharp = eqx.tree_at(lambda c: c.kp, pi, pi.kp * 16)               # Ms ≈ 2.41
    kp, ki = np.diag(np.asarray(sharp.kp)), np.diag(np.asarray(sharp.kp / sharp.ti))
    mimo = MIMOPI(kp=jnp.asarray(kp + 0.05), ki=jnp.asarray(ki + 0.001), u0=pi.u0, ts=pi.ts)
    return plant, {"pi": pi, "sharp": sharp, "mimo": mimo}


@pytest.mark.parametrize("name", ["pi", "sharp", "mimo"])
def test_soft_ms_bounds_the_peak_sensitivity(name):
    plant, loops = _loops()
    z, G = model_response(plant, 200)
    soft = float(soft_peak_sensitivity(loops[name], z, G, t=0.01))
    hard = peak_sensitivity(plant, loops[name], n_freq=200)["ms"]
    assert hard <= soft <= hard + 0.01 * np.log(200) + 1e-12


@pytest.mark.parametrize("name", ["sharp", "mimo"])
def test_ms_penalty_gradient_matches_central_differences(name):
    plant, loops = _loops()
    z, G = model_response(plant, 200)
    ctrl = loops[name]
    params, static = eqx.partition(ctrl, eqx.is_inexact_array)
    flat, unravel = ravel_pytree(params)

    @jax.jit
    def f(th):
        return ms_penalty(eqx.combine(unravel(th), static), z, G, 1.5, 10.0)

    assert float(f(flat)) > 0.0
    np.testing.assert_allclose(jax.grad(f)(flat), central_difference(f, flat), rtol=1e-5,
                               atol=1e-8)


def test_ms_penalty_is_zero_inside_the_limit_and_for_other_families():
    plant, loops = _loops()
    z, G = model_response(plant, 200)
    assert float(ms_penalty(loops["pi"], z, G, 2.0, 10.0)) == 0.0
    assert float(ms_penalty(design("lqg", plant), z, G, 1.0, 10.0)) == 0.0
