"""`recurrence.radiative`: its hand-written forward-mode rule against JAX's derivative of the plain
scan and against central differences; primal against the plain scan."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo.diagnose.recurrence import KELVIN, radiative

jax.config.update("jax_enable_x64", True)


def _plain(E, P, a, r, F, sig, s0):
    """The recurrence as the scan body writes it, differentiated by JAX itself."""
    n = a.shape[0]

    def body(s, inp):
        fk, sk = inp
        q = a * s[:n] - r * ((s[:n] + KELVIN) ** 4 - sk)
        return jnp.sum(E * s[None, :], axis=1) + jnp.sum(P * q[None, :], axis=1) + fk, s[:n]

    return jax.lax.scan(body, s0, (F, sig))[1]


def _problem(n=2, m=5, T=60, seed=0):
    rng = np.random.default_rng(seed)
    E = 0.9 * np.eye(m) + 0.02 * rng.standard_normal((m, m))
    P = 0.5 * rng.standard_normal((m, n))
    a = 1e-3 * (1 + rng.random(n))
    r = a / (4 * (40 + KELVIN) ** 3) * rng.random(n)
    F = rng.standard_normal((T, m))
    sig = (25.0 + rng.standard_normal((T, n)) + KELVIN) ** 4
    s0 = 30.0 + rng.standard_normal(m)
    return tuple(jnp.asarray(v) for v in (E, P, a, r, F, sig, s0))


@pytest.mark.parametrize("n, m", [(1, 3), (3, 9)])
def test_primal_and_jvp_match_plain_scan(n, m):
    args = _problem(n, m)
    np.testing.assert_allclose(radiative(*args), _plain(*args), rtol=1e-12, atol=1e-10)
    rng = np.random.default_rng(1)
    tan = tuple(jnp.asarray(rng.standard_normal(x.shape) * (1e-12 if i in (3, 5) else 1.0) * np.abs(x).mean())
                for i, x in enumerate(args))
    y1, d1 = jax.jvp(radiative, args, tan)
    y2, d2 = jax.jvp(_plain, args, tan)
    np.testing.assert_allclose(d1, d2, rtol=1e-9, atol=1e-9 * float(jnp.abs(d2).max()))


def test_jvp_central_differences_and_reverse_mode():
    args = _problem(2, 6, T=40, seed=3)
    rng = np.random.default_rng(4)
    tan = [jnp.asarray(rng.standard_normal(x.shape)) * 1e-3 * (jnp.abs(x).mean() + 1e-30) for x in args]
    _, d = jax.jvp(radiative, args, tuple(tan))
    h = 1e-3
    plus = radiative(*[x + h * t for x, t in zip(args, tan)])
    minus = radiative(*[x - h * t for x, t in zip(args, tan)])
    np.testing.assert_allclose(d, (plus - minus) / (2 * h), rtol=1e-6, atol=1e-8)
    # reverse mode goes through the transposed tangent rule
    w = jnp.asarray(rng.standard_normal(d.shape))
    g = jax.grad(lambda F: jnp.sum(w * radiative(*args[:4], F, *args[5:])))(args[4])
    np.testing.assert_allclose(jnp.sum(g * tan[4]),
                               jnp.sum(w * jax.jvp(lambda F: radiative(*args[:4], F, *args[5:]),
                                                   (args[4],), (tan[4],))[1]), rtol=1e-10)
