"""Input design for identification experiments: band-limited PRBS, crest factor, periodogram.

The thesis (§3.1.1) excites every heater channel with its own pseudo-random binary signal:
binary, so the crest factor is at its lower bound of 1, with its power concentrated in the
band where the bed responds (around 0.1 Hz and below at Ts = 1 s), and generated
independently per channel so that no correlation enters the system input.

Here a PRBS is a random telegraph signal: it alternates between two levels and holds each for
a random number of samples drawn uniformly from `hold = (min, max)`. A hold of h samples is half
a period of a square wave at $1 / (2 h T_s)$ Hz, so a band `(f_lo, f_hi)` in Hz maps to holds
$h_{min} = \\mathrm{round}(1 / (2 f_{hi} T_s))$ and $h_{max} = \\mathrm{round}(1 / (2 f_{lo} T_s))$.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .errors import DataError

#: default hold range in samples (the standard W1 identification workload uses 3..15)
DEFAULT_HOLD = (3, 15)


def _as_key(key_or_seed):
    bad = DataError(f"prbs: key_or_seed must be an integer seed or a jax.random key, got {key_or_seed!r}"[:120])
    if isinstance(key_or_seed, (bool, np.bool_)):
        raise bad
    if isinstance(key_or_seed, (int, np.integer)):
        if key_or_seed < 0:
            raise DataError(f"prbs: seed must be a non-negative integer, got {key_or_seed}")
        return jax.random.key(int(key_or_seed))
    if not isinstance(key_or_seed, (jax.Array, np.ndarray)):
        raise bad
    if jax.dtypes.issubdtype(key_or_seed.dtype, jax.dtypes.prng_key):
        if key_or_seed.shape != ():
            raise DataError(f"prbs: expected a single key, got a key array of shape {key_or_seed.shape}")
        return key_or_seed
    if key_or_seed.dtype == np.uint32 and key_or_seed.shape == (2,):   # legacy raw key
        return jax.random.wrap_key_data(jnp.asarray(key_or_seed))
    raise bad


def hold_from_band(band: tuple[float, float], ts: float = 1.0) -> tuple[int, int]:
    """Hold range in samples for a PRBS with its power in `band = (f_lo, f_hi)` Hz.

    $h_{min} = \\max(1, \\mathrm{round}(1 / (2 f_{hi} T_s)))$,
    $h_{max} = \\max(h_{min}, \\mathrm{round}(1 / (2 f_{lo} T_s)))$.
    """
    try:
        f_lo, f_hi = (float(b) for b in band)
    except (TypeError, ValueError):
        raise DataError(f"prbs: band must be a pair (f_lo, f_hi) in Hz, got {band!r}") from None
    nyq = 0.5 / ts
    if not (math.isfinite(f_lo) and math.isfinite(f_hi)) or not (0 < f_lo < f_hi <= nyq):
        raise DataError(f"prbs: band ({f_lo:g}, {f_hi:g}) Hz must satisfy 0 < f_lo < f_hi <= "
                        f"{nyq:g} Hz (the Nyquist frequency at Ts = {ts:g} s)")
    h_min = max(1, round(1.0 / (2.0 * f_hi * ts)))
    h_max = max(h_min, round(1.0 / (2.0 * f_lo * ts)))
    return h_min, h_max


def prbs(key_or_seed, n_samples: int, n_channels: int = 1, *,
         levels: tuple[float, float] = (0.3, 0.7), band: tuple[float, float] | None = None,
         hold: tuple[int, int] | None = None, ts: float = 1.0) -> Float[Array, "T n"]:
    """Band-limited pseudo-random binary signal, independent per channel.

    Each channel alternates between `levels[0]` and `levels[1]`, holding each value for a random
    number of samples drawn uniformly from `hold` (inclusive), starting at a random level. Give
    either `hold` in samples or `band = (f_lo, f_hi)` in Hz (see `hold_from_band`); with neither,
    `hold = (3, 15)` puts the power at about 0.1 Hz and below for Ts = 1 s (thesis §3.1.1).

    **Arguments:**
    - `key_or_seed`: a `jax.random` key or a non-negative integer seed; the same one gives the
      same signal.
    - `n_samples`, `n_channels`: the shape `(T, n)` of the result.
    - `levels`: the two values (power fractions on the printer), `levels[0] < levels[1]`.
    - `band` or `hold`: the spectral shaping; `ts` the sample time in s (used with `band`).

    **Returns:** `(n_samples, n_channels)` array taking only the two `levels`.
    """
    if not (isinstance(n_samples, (int, np.integer)) and n_samples >= 1):
        raise DataError(f"prbs: n_samples must be a positive integer, got {n_samples!r}")
    if not (isinstance(n_channels, (int, np.integer)) and n_channels >= 1):
        raise DataError(f"prbs: n_channels must be a positive integer, got {n_channels!r}")
    if not (isinstance(ts, (int, float, np.floating)) and math.isfinite(ts) and ts > 0):
        raise DataError(f"prbs: sample time ts must be positive, got {ts!r}")
    try:
        lo, hi = (float(v) for v in levels)
    except (TypeError, ValueError):
        raise DataError(f"prbs: levels must be a pair (low, high), got {levels!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi:
        raise DataError(f"prbs: levels ({lo:g}, {hi:g}) must be finite with low < high")
    if band is not None and hold is not None:
        raise DataError("prbs: give either `band` (Hz) or `hold` (samples), not both")
    if band is not None:
        h_min, h_max = hold_from_band(band, ts)
    else:
        h = DEFAULT_HOLD if hold is None else hold
        try:
            h_min, h_max = (int(v) for v in h)
            ok = all(float(v) == int(v) for v in h)
        except (TypeError, ValueError):
            raise DataError(f"prbs: hold must be a pair (min, max) of samples, got {hold!r}") from None
        if not ok or not 1 <= h_min <= h_max:
            raise DataError(f"prbs: hold {tuple(h)} must be integers with 1 <= min <= max")
    key = _as_key(key_or_seed)
    return _prbs(key, int(n_samples), int(n_channels), h_min, h_max, lo, hi)


@functools.partial(jax.jit, static_argnums=(1, 2))
def _prbs(key, T, n, h_min, h_max, lo, hi):
    n_holds = T + 1              # enough holds to cover T samples for any h_min >= 1

    def one(k):
        k_start, k_hold = jax.random.split(k)
        start = jax.random.bernoulli(k_start).astype(jnp.int32)
        holds = jax.random.randint(k_hold, (n_holds,), h_min, h_max + 1)
        edges = jnp.cumsum(holds)                       # sample index of each switch
        n_switch = jnp.searchsorted(edges, jnp.arange(T), side="right", method="sort")
        return (start + n_switch) % 2

    bits = jax.vmap(one)(jax.random.split(key, n)).T   # (T, n)
    return jnp.where(bits == 1, hi, lo)


def crest_factor(u: ArrayLike, centre: float | ArrayLike | None = None) -> Float[Array, "*n"]:
    """Crest factor per channel (thesis eq. 3.1):
    $C_r = \\sqrt{\\max_t (u_t - c)^2 \\, / \\, \\frac1N \\sum_t (u_t - c)^2}$.

    The lower bound 1 is reached by a binary signal around its centre. `centre` defaults to the
    mid-range $(\\max u + \\min u)/2$ of each channel (0.5 for the thesis' 0–1 input).

    **Returns:** a scalar for a 1-D signal, `(n,)` for a `(T, n)` signal.
    """
    u = jnp.asarray(u)
    if u.ndim not in (1, 2) or u.shape[0] < 1:
        raise DataError(f"crest_factor: expected a (T,) or (T, n) signal, got shape {u.shape}")
    c = (jnp.max(u, axis=0) + jnp.min(u, axis=0)) / 2 if centre is None else jnp.asarray(centre)
    d2 = (u - c) ** 2
    ms = jnp.mean(d2, axis=0)
    if not isinstance(ms, jax.core.Tracer) and bool(jnp.any(ms == 0)):
        raise DataError("crest_factor: a channel equals its centre at every sample (no power)")
    return jnp.sqrt(jnp.max(d2, axis=0) / ms)


def periodogram(x: ArrayLike, ts: float = 1.0, *, detrend: bool = True
                ) -> tuple[Float[Array, " nf"], Float[Array, "nf ..."]]:
    """One-sided periodogram (power spectral density) of each column.

    $P(f_k) = \\frac{c_k T_s}{N} |\\sum_t x_t e^{-i 2\\pi k t / N}|^2$ at $f_k = k / (N T_s)$,
    with $c_k = 2$ except at 0 and the Nyquist frequency; the mean is removed first when
    `detrend` (matches `scipy.signal.periodogram` with its defaults).

    **Returns:** `(freqs in Hz, power in units²/Hz)`; power is `(nf,)` or `(nf, n)`.
    """
    x = jnp.asarray(x)
    if x.ndim not in (1, 2) or x.shape[0] < 2:
        raise DataError(f"periodogram: expected a (T,) or (T, n) signal with T >= 2, got shape {x.shape}")
    if not (math.isfinite(ts) and ts > 0):
        raise DataError(f"periodogram: sample time must be positive, got {ts}")
    N = x.shape[0]
    if detrend:
        x = x - jnp.mean(x, axis=0)
    X = jnp.fft.rfft(x, axis=0)
    p = (jnp.abs(X) ** 2) * (ts / N)
    scale = jnp.full(X.shape[0], 2.0, dtype=p.dtype).at[0].set(1.0)
    if N % 2 == 0:
        scale = scale.at[-1].set(1.0)
    p = p * (scale if x.ndim == 1 else scale[:, None])
    freqs = jnp.fft.rfftfreq(N, d=ts)
    return freqs, p
