"""Record lengths from a small set: padding along time, and the residual masked to the record.

A process that compiles one program per record length it meets holds ever more compiled code
(every XLA CPU executable keeps memory maps, and Linux allows a process 65,530 of them). The
PEM solves (`pem.minimize`, `minimize_many`, `minimize_matrix_free`) therefore pad a record of
$T$ samples to `bucket(T)` (four lengths per octave, at most 25 % more samples): every array
whose time axis has $T$ entries is extended by repeating its last sample, and the residual rows
from $T$ on are selected away (`masked_residual`), the mean taken over the $T n_y$ true ones
(`masked_cost`). For a residual that is causal in its data (the error at $t$ depends on the
samples up to $t$: every one-step prediction and simulation error is), the rows before $T$ are
those of the unpadded record, so criterion, Jacobian and solve agree with it to round-off.
The true length travels as a traced scalar: all lengths of a bucket share one program.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

#: padded record lengths: m * 2**k with m in these mantissas (four steps per octave)
BUCKET_MANTISSAS = (4, 5, 6, 7)


def bucket(T: int) -> int:
    """The padded length of a record of `T` samples: the smallest $m 2^k \\ge T$ with $m$ in
    `BUCKET_MANTISSAS`, $k \\ge 0$ (at most 25 % above T; T itself below 8)."""
    T = int(T)
    if T < 8:
        return T
    k = T.bit_length() - 3                  # T in [4 * 2^k, 8 * 2^k)
    return min(m << k for m in BUCKET_MANTISSAS + (8,) if m << k >= T)


def _is_array(x) -> bool:
    return isinstance(x, (np.ndarray, jax.Array))


#: `residual_length`'s memo: (function, argument structure and shapes) -> T, bounded
_LENGTHS: dict = {}
_LENGTHS_SIZE = 256


def _signature(residual_fn, theta, args, batch_dims):
    leaves, treedef = jax.tree_util.tree_flatten(args)
    parts = tuple((x.shape, str(x.dtype)) if _is_array(x) else x for x in leaves)
    key = (residual_fn, treedef, parts, tuple(theta.shape), str(theta.dtype), batch_dims)
    try:
        hash(key)
    except TypeError:
        return None
    return key


def residual_length(residual_fn, theta, args: Any, batch_dims: int = 0) -> int:
    """Rows `T` of `residual_fn(theta, args)` (traced abstractly once per function and argument
    shapes: nothing is compiled); with `batch_dims=1` `theta (M, p)` and `args` carry a problem
    axis first."""
    key = _signature(residual_fn, theta, args, batch_dims)
    if key is not None and key in _LENGTHS:
        return _LENGTHS[key]
    fn = eqx.filter_vmap(residual_fn) if batch_dims else residual_fn
    T = int(eqx.filter_eval_shape(fn, theta, args).shape[batch_dims])
    if key is not None:
        if len(_LENGTHS) >= _LENGTHS_SIZE:
            _LENGTHS.pop(next(iter(_LENGTHS)))
        _LENGTHS[key] = T
    return T


def pad_time(args: Any, T: int, length: int, batch_dims: int = 0) -> Any:
    """`args` with every array whose axis `batch_dims` (the time axis) has `T` entries extended
    to `length` by repeating its last sample (laid out in NumPy: nothing compiles per length).
    Other leaves are returned as they are."""
    if length == T:
        return args

    def one(x):
        if not _is_array(x) or x.ndim <= batch_dims or x.shape[batch_dims] != T:
            return x
        widths = [(0, 0)] * x.ndim
        widths[batch_dims] = (0, length - T)
        return jax.device_put(np.pad(np.asarray(x), widths, mode="edge"))

    return jax.tree_util.tree_map(one, args)


def masked_residual(residual_fn, theta, args, n_valid):
    """`residual_fn(theta, args)` with the rows from `n_valid` on set to zero (a select: their
    Jacobian rows are zero too, whatever a padded sample computed)."""
    r = residual_fn(theta, args)
    keep = jnp.arange(r.shape[0]).reshape((-1,) + (1,) * (r.ndim - 1)) < n_valid
    return jnp.where(keep, r, 0.0)


def masked_cost(residual_fn, theta, args, n_valid):
    """$V(\\theta)$ over the first `n_valid` residual rows: their squared sum over
    $n_{valid} n_y$ (the criterion of the unpadded record)."""
    r = masked_residual(residual_fn, theta, args, n_valid)
    return jnp.sum(r ** 2) / (n_valid * (r.size // r.shape[0]))


def padded(residual_fn, theta0, args, batch_dims: int, pad: bool):
    """`(args padded to the bucket of the residual's length, that length)`."""
    shape = (theta0.shape[0], theta0.shape[-1]) if batch_dims else (theta0.shape[-1],)
    probe = jax.ShapeDtypeStruct(shape, theta0.dtype)
    T = residual_length(residual_fn, probe, args, batch_dims)
    if not pad:
        return args, T
    return pad_time(args, T, bucket(T), batch_dims), T


def true_count(r, n_valid):
    """True residual entries: `n_valid` rows of `r`'s row size."""
    return jnp.asarray(n_valid * (r.size // r.shape[0]), r.dtype)


def true_length(T: int):
    """The true length as a placed array (a traced argument: one program per bucket)."""
    return jax.device_put(np.asarray(T, np.int32))


__all__ = ["BUCKET_MANTISSAS", "bucket", "masked_cost", "masked_residual", "pad_time", "true_count", "true_length",
           "padded", "residual_length"]
