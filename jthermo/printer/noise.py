"""The printer's measurement noise drawn one sample at a time inside a closed-loop scan, with
the same random bits as the whole-run draw (`Printer.sample_noise`).

With JAX's partitionable Threefry (`jax_threefry_partitionable`, JAX's default), element `i`
of `jax.random.normal(key, (T, n), float64)` is a function of `key` and `i` alone: the hash
$(b_1, b_2) = \\mathrm{threefry}_{2\\times 32}(key, (i_{hi}, i_{lo}))$, the 64 bits
$b_1 2^{32} + b_2$ made a uniform $u \\in (-1, 1)$ from their top 52 bits, then
$\\sqrt{2}\\,\\mathrm{erf}^{-1}(u)$. `normal_row` computes row `t` of that array from those
indices, so a scan draws each sample's noise when it needs it: no `(B, T, ny)` noise array,
and the same draws (`tests/closedloop/test_noise_in_scan.py` holds them bit for bit; the
noise built from them agrees to float64 round-off).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.random import threefry2x32_p
from jaxtyping import Array, Float

_ONE_BITS = int(np.array(1.0, np.float64).view(np.uint64))
_LO = float(np.nextafter(-1.0, 0.0))    # jax.random.normal's lower bound of u


def in_scan_supported(dtype) -> bool:
    """Whether `normal_row` reproduces `jax.random.normal` here: float64 draws under the
    partitionable Threefry (else draw the whole run with `Printer.sample_noise`)."""
    return (jnp.dtype(dtype) == jnp.float64 and bool(jax.config.jax_threefry_partitionable)
            and jax.random.key_impl(jax.random.key(0)) == "threefry2x32")


def normal_row(key, t, n: int) -> Float[Array, " n"]:
    """Row `t` (traced) of `jax.random.normal(key, (T, n), float64)`, for any `T > t`.

    **Arguments:** `key` a typed PRNG key (Threefry), `t` the sample index, `n` the row width.
    """
    kd = jax.random.key_data(key)
    idx = (jnp.asarray(t, jnp.uint64) * jnp.uint64(n) + jnp.arange(n, dtype=jnp.uint64))
    b1, b2 = threefry2x32_p.bind(kd[0], kd[1], (idx >> jnp.uint64(32)).astype(jnp.uint32),
                                 idx.astype(jnp.uint32))
    bits = (b1.astype(jnp.uint64) << jnp.uint64(32)) | b2.astype(jnp.uint64)
    mant = (bits >> jnp.uint64(64 - 52)) | jnp.uint64(_ONE_BITS)
    floats = jax.lax.bitcast_convert_type(mant, jnp.float64) - 1.0
    u = jax.lax.max(jnp.float64(_LO), floats * (1.0 - _LO) + _LO)
    return jnp.float64(np.sqrt(2.0)) * jax.lax.erf_inv(u)


class NoiseStream(eqx.Module):
    """`Printer.sample_noise(key, T, white_std)` one sample at a time: `init()` the filter
    state, `at(k, c)` the noise `(ny,)` of sample `k` and the next state (the sensor noise's
    AR(1) part, $c_0 = \\sigma_c e_0$, $c_k = a c_{k-1} + \\sigma_c \\sqrt{1 - a^2}\\, e_k$).
    Built by `Printer.noise_stream`; each sample's draws equal row `k` of the whole run's."""

    keys: Array                       # the three keys of `sample_noise` (white, white, AR)
    white_std: float = eqx.field(static=True)
    sensor: dict | None               # the `sensor_noise` effect's parameters, or None
    ny: int = eqx.field(static=True)
    zones: int = eqx.field(static=True)

    def init(self) -> Float[Array, " zones"]:
        return jnp.zeros((self.zones,), jnp.float64)

    def at(self, k, c) -> tuple[Float[Array, " ny"], Float[Array, " zones"]]:
        v = self.white_std * normal_row(self.keys[0], k, self.ny)
        if self.sensor is None:
            return v, c
        p = self.sensor
        v = v + p["white_std_C"] * normal_row(self.keys[1], k, self.ny)
        e = normal_row(self.keys[2], k, self.zones)
        a = p["pole"]
        c = jnp.where(k == 0, p["coloured_std_C"] * e,
                      a * c + p["coloured_std_C"] * jnp.sqrt(1.0 - a ** 2) * e)
        return v.at[:self.zones].add(c), c
