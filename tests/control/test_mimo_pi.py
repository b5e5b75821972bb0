"""MIMO PI: equal to the decoupled PI it starts from, masks that hold under gradients, and the
peak sensitivity against python-control's frequency response."""

import control as ct
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.control import LQG, MIMOPI, design, mimo_from, neighbour_mask
from jthermo.control.margins import peak_sensitivity
from jthermo.errors import ControlError

from .loop import bed_plant, closed_loop

N, T = 3, 300


def _step_r(plant, size=25.0):
    return jnp.broadcast_to(plant.y0 + jnp.where(jnp.arange(T)[:, None] < 100, size, 0.0), (T, N))


def test_mimo_from_decoupled_is_the_same_controller_through_saturation():
    plant = bed_plant(N, seed=2)
    dec = design("pi_decoupled", plant)
    r = _step_r(plant)
    y1, u1 = closed_loop(dec, plant, r)
    y2, u2 = closed_loop(mimo_from(dec), plant, r)
    assert float(jnp.max(u1)) == 1.0            # the heaters saturate: anti-windup matters
    np.testing.assert_allclose(u2, u1, rtol=0, atol=1e-12)
    np.testing.assert_allclose(y2, y1, rtol=0, atol=1e-10)


def test_neighbour_mask_removes_entries_and_their_gradients():
    plant = bed_plant(4, seed=0)
    edges = ((0, 1), (1, 2), (2, 3))
    c = mimo_from(design("pi_lambda", plant), edges=edges)
    m = np.asarray(neighbour_mask(4, edges))
    assert m[0, 2] == 0.0 and m[0, 1] == 1.0 and np.all(np.diag(m) == 1.0)
    c = MIMOPI(kp=c.kp + 0.3, ki=c.ki + 0.01, u0=c.u0, mask=c.mask, ts=c.ts)
    kp, _ = c.gains()
    assert np.all(np.asarray(kp)[m == 0] == 0.0)
    r = jnp.broadcast_to(plant.y0 + 2.0, (100, 4))

    def cost(kp):
        y, _ = closed_loop(MIMOPI(kp=kp, ki=c.ki, u0=c.u0, mask=c.mask, ts=c.ts), plant, r)
        return jnp.mean((y - r) ** 2)

    g = np.asarray(jax.grad(cost)(c.kp))
    assert np.all(g[m == 0] == 0.0) and np.all(np.isfinite(g)) and np.any(g[m == 1] != 0.0)


def test_mimo_pi_checks_shapes():
    with pytest.raises(ControlError, match="must be square"):
        MIMOPI(kp=jnp.zeros((2, 3)), ki=jnp.zeros((2, 2)), u0=jnp.zeros(2))


def _kyu_ct(ctrl, ts):
    """y -> u of a MIMO PI as a python-control system: -(Kp + Ki z/(z-1))."""
    kp, ki = (np.asarray(g) for g in ctrl.gains())
    n = kp.shape[0]
    return ct.ss(np.eye(n), -ki, np.eye(n), -(kp + ki), ts)


@pytest.mark.parametrize("family", ["pi_lambda", "pi_decoupled", "lqg"])
def test_peak_sensitivity_against_python_control(family):
    plant = bed_plant(N, seed=4)
    ctrl = design(family, plant)
    got = peak_sensitivity(plant, ctrl, n_freq=400)
    G = ct.ss(np.asarray(plant.A), np.asarray(plant.B), np.asarray(plant.C),
              np.asarray(plant.D), 1.0)
    if isinstance(ctrl, LQG):
        from jthermo.control.margins import controller_response
        w = np.logspace(-4, np.log10(np.pi), 400)
        K = controller_response(ctrl, np.exp(1j * w))
        Gf = np.moveaxis(G.frequency_response(w).frdata, -1, 0)
        sig = np.linalg.svd(np.linalg.inv(np.eye(N) - Gf @ K), compute_uv=False)[:, 0]
        ref, stable = sig.max(), True
    else:
        K = _kyu_ct(mimo_from(ctrl) if not isinstance(ctrl, MIMOPI) else ctrl, 1.0)
        S = ct.feedback(ct.ss(np.zeros((N, N)), np.zeros((N, N)), np.zeros((N, N)), np.eye(N), 1.0),
                        G * K, sign=1)
        w = np.logspace(-4, np.log10(np.pi), 400)
        fr = np.moveaxis(S.frequency_response(w).frdata, -1, 0)
        ref = np.linalg.svd(fr, compute_uv=False)[:, 0].max()
        stable = bool(np.all(np.abs(S.poles()) < 1.0))
    assert got["ms"] == pytest.approx(ref, rel=1e-9)
    assert got["stable"] == stable and got["ms"] >= 1.0


def test_peak_sensitivity_flags_an_unstable_loop():
    plant = bed_plant(N, seed=4)
    c = mimo_from(design("pi_lambda", plant))
    hot = MIMOPI(kp=40.0 * c.kp, ki=c.ki, u0=c.u0, ts=c.ts)
    out = peak_sensitivity(plant, hot)
    assert not out["stable"]
    with pytest.raises(ControlError, match="no linear feedback form"):
        peak_sensitivity(plant, design("imc", plant))
