"""The printer's measurement noise drawn one sample at a time inside a closed-loop scan: the
distribution of the whole-run draw (`Printer.sample_noise`) at about a quarter of its cost
(measured at N = 16, B = 256, T = 3600 by `python benchmarks/simulate_noise_options.py`).

`Printer.sample_noise` draws three float64 normal arrays: the scenario's white noise, the
`sensor_noise` effect's white part (both on every output) and the innovations of its AR(1)
part (on the zone sensors). Drawn inside a scan, sample $k$ of the stream instead takes one
float32 normal vector $e_k = \\mathcal{N}(0, I_{n_y + n_z})$ from the key
`jax.random.fold_in(key, k)`, cast to the plant's dtype, and forms

$v_k = \\sqrt{\\sigma_w^2 + \\sigma_s^2}\\; e_k[:n_y] + (c_k, 0)$,
$c_0 = \\sigma_c e_0[n_y:]$, $c_k = a c_{k-1} + \\sigma_c \\sqrt{1 - a^2}\\, e_k[n_y:]$:

the two white parts as one draw of their summed variance (the same distribution) and every
draw in float32 (24-bit normals, far finer than the noise's 0.05 °C steps). Per channel the
same standard deviation and autocorrelation as `sample_noise`, other draws: a run of
`closedloop.run` on the printer is a statistically equal, not an identical, realisation of
`make_scenario`'s noise (`tests/closedloop/test_engine_noise.py` checks the statistics;
`python benchmarks/simulate_noise_options.py` times both and reports the statistics).
Deterministic: the same key gives the same stream.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

#: samples of the stream drawn at once (`NoiseStream.at`)
CHUNK = 64


class NoiseStream(eqx.Module):
    """The measurement noise of one run, one sample at a time: `init()` the state (the AR(1)
    state and a buffer of draws), `at(k, state)` the noise `(ny,)` of sample `k` (traced,
    visited in order from 0) and the next state. Built by `Printer.noise_stream`; the recipe
    is in the module docstring."""

    key: Array                        # a typed PRNG key; sample k draws from fold_in(key, k)
    white_std: float = eqx.field(static=True)   # °C, the scenario's white noise
    sensor: dict | None               # the `sensor_noise` effect's parameters, or None
    ny: int = eqx.field(static=True)
    zones: int = eqx.field(static=True)
    dtype: str = eqx.field(static=True, default="float64")

    def init(self):
        """The stream's state before sample 0: the AR(1) state and a buffer of `CHUNK` draws."""
        return (jnp.zeros((self.zones,), self.dtype),
                jnp.zeros((CHUNK, self._n_draws()), jnp.float32))

    def _n_draws(self) -> int:
        return self.ny + (0 if self.sensor is None else self.zones)

    def _draws(self, k0):
        """The float32 normal vectors of samples `k0 .. k0 + CHUNK - 1`, `(CHUNK, n)`."""
        n_e = self._n_draws()
        return jax.vmap(lambda j: jax.random.normal(jax.random.fold_in(self.key, j), (n_e,),
                                                    jnp.float32))(k0 + jnp.arange(CHUNK))

    def at(self, k, state):
        """The noise `(ny,)` of sample `k` (traced) and the next state. Samples are drawn
        `CHUNK` at a time into the state's buffer, when `k` is a multiple of `CHUNK` (the scan
        visits every sample in order from 0): the same values as one draw per sample, but
        each random vector is computed once (fused into every consumer, XLA evaluated the
        Threefry hash three times per sample) and in larger vectorised kernels."""
        c, buf = state
        j = k % CHUNK
        buf = jax.lax.cond(j == 0, lambda b: self._draws(k), lambda b: b, buf)
        e = jax.lax.dynamic_index_in_dim(buf, j, keepdims=False).astype(self.dtype)
        v, c = self.shape_noise(k, c, e)
        return v, (c, buf)

    def shape_noise(self, k, c, e):
        if self.sensor is None:
            return self.white_std * e, c
        p = self.sensor
        white = jnp.sqrt(self.white_std ** 2 + p["white_std_C"] ** 2)
        ec, a = e[self.ny:], p["pole"]
        c = jnp.where(k == 0, p["coloured_std_C"] * ec,
                      a * c + p["coloured_std_C"] * jnp.sqrt(1.0 - a ** 2) * ec)
        return (white * e[:self.ny]).at[:self.zones].add(c), c

    def sample(self, n_samples: int) -> Float[Array, "T ny"]:
        """The first `n_samples` samples of the stream as one `(T, ny)` array (for tests and
        figures: the scan draws them one at a time)."""
        def body(c, k):
            v, c = self.at(k, c)
            return c, v

        return jax.lax.scan(body, self.init(), jnp.arange(n_samples))[1]
