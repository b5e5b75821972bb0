"""A tiny closed loop for controller tests: a linear bed plant and a scanned simulation."""

import jax
import jax.numpy as jnp
import numpy as np

from jthermo.models import StateSpace


def bed_plant(n=3, seed=0, u_op=0.3, y_amb=20.0):
    """An n-zone bed: diagonal A in [0.92, 0.96], grid-coupled B (as the shared workload W1)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.92, 0.96, n)
    b = rng.uniform(0.15, 0.25, n)
    pos = np.arange(n, dtype=float)
    B = b[:, None] * np.exp(-((pos[:, None] - pos[None, :]) ** 2) / 0.8)
    A = np.diag(a)
    G0 = np.linalg.solve(np.eye(n) - A, B)
    y_op = y_amb + G0 @ np.full(n, u_op)
    return StateSpace(A, B, np.eye(n), u0=np.full(n, u_op), y0=y_op)


def closed_loop(ctrl, plant, r, d=None, x0=None):
    """Simulate; `r` (T, ny) set points, `d` (T, nx) additive state disturbances.
    Returns (y, u) of shape (T, n)."""
    x0 = plant.initial_state(plant.y0) if x0 is None else x0
    d = jnp.zeros((r.shape[0], plant.A.shape[0])) if d is None else d

    def body(c, inp):
        x, s = c
        rk, dk = inp
        y = plant.output(x)
        u, s = ctrl.step(s, y, rk)
        u = jnp.clip(u, 0.0, 1.0)
        return (plant.step(x, u) + dk, s), (y, u)

    s0 = ctrl.init(plant.output(x0), r[0])
    _, (ys, us) = jax.lax.scan(body, (x0, s0), (r, d))
    return ys, us


def step_reference(plant, T, size=1.0, at=0):
    r = np.broadcast_to(np.asarray(plant.y0), (T, plant.C.shape[0])).copy()
    r[at:] += size
    return jnp.asarray(r)
