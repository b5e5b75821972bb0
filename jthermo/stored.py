"""Traced programs and numeric results kept on disk, beside JAX's compilation cache.

`exported_call` keeps a program's trace (a serialized `jax.export`), so that a later process
neither traces nor lowers it again; `cached_arrays` keeps the numbers a deterministic program
returned, so that a later process reads them instead of running it. Both write into the
cache directory of `jthermo.runtime` (`EXPORT_SUBDIR`), under a key made of the program, its
inputs' structure, jthermo's source and the package versions, and both do nothing with the
cache off or inside a JAX trace.
"""

from __future__ import annotations

import functools
import os
import tempfile
from pathlib import Path

from .runtime import cache_dir, lowering_tags, top_level

#: subdirectory of the cache directory holding serialized `jax.export` programs (JAX's own
#: cache reads and evicts only its `*-cache` entries, so it leaves these alone)
EXPORT_SUBDIR = "jthermo-export"
#: the most exported programs kept; beyond it the least recently used are removed
MAX_EXPORTS = 64
#: bumped when the file's meaning changes
_EXPORT_FORMAT = "1"
#: JAX settings that change what a trace produces: part of an exported program's key
_TRACE_FLAGS = ("jax_enable_x64", "jax_threefry_partitionable", "jax_default_prng_impl",
                "jax_default_matmul_precision", "jax_numpy_dtype_promotion",
                "jax_numpy_rank_promotion")


def exported_call(fn, args: tuple, fallback, compiler_options: dict | None = None):
    """`fn(*args)` without tracing `fn` when an earlier process already did: its traced
    program is kept as a serialized `jax.export` in the cache directory (`EXPORT_SUBDIR`),
    and the executable comes from the persistent compilation cache as before.

    `args`: pytrees (equinox modules) whose array leaves are the program's inputs; every
    other leaf (strings, numbers, static fields) and the tree structure are part of the
    file's key, with the shapes and dtypes of the arrays, a hash of jthermo's source, the
    versions of JAX, jaxlib, equinox and NumPy, the JAX settings that shape a trace
    (`_TRACE_FLAGS`: x64, the PRNG, precision, promotion) and the Threefry lowering
    (`unroll_threefry`). Outputs come back as arrays (a Python scalar as a 0-d array).

    `fallback` (`fn` jitted with `compiler_options`) runs instead, as before, wherever no
    export can serve: the cache off (`--no-cache`, `JTHERMO_NO_CACHE`, an unwritable
    directory: then no file is read or written), inside a JAX trace, a leaf whose repr is
    not stable across processes, `jax.export` or its `flatbuffers` dependency missing, or a
    file that cannot be read, is corrupt or does not match (it is replaced). Files are
    written to a temporary name and renamed: processes running at once never see a torn
    file. Never raises for the export itself; errors of `fn` propagate as from `fallback`."""
    program = None
    if cache_dir() is not None and top_level():
        try:
            program = _exported_program(fn, args)
        except Exception:  # noqa: BLE001  (no export support, an unexportable program)
            program = None
    if program is None:
        return fallback(*args)
    exp, arrays = program
    try:
        return _caller(exp, compiler_options)(*arrays)
    except Exception:  # noqa: BLE001  (a program this JAX cannot call: trace it afresh)
        return fallback(*args)


def exported_compile(fn, args: tuple, compiler_options: dict | None = None) -> bool:
    """Prepare `exported_call(fn, args, ..., compiler_options)` without running it: read (or
    trace and write) its exported program and compile it for these argument shapes, so that
    the call itself finds both in this process (`_programs`, `_callers` and JAX's own caches).
    Meant for a background thread while the caller computes the real arguments (same tree
    structure, static leaves, shapes and dtypes; the values may differ). True when prepared;
    False (nothing done) where `exported_call` would use its fallback or anything failed."""
    if cache_dir() is None or not top_level():
        return False
    try:
        program = _exported_program(fn, args)
        if program is None:
            return False
        exp, arrays = program
        _caller(exp, compiler_options).lower(*arrays).compile()
        return True
    except Exception:  # noqa: BLE001  (preparation is an optimisation: the call itself decides)
        return False


#: this process's programs read or written by `exported_call`: path -> (file's stat, header,
#: Exported), and their jitted callers: (id of the Exported, options) -> (Exported, jitted call)
_programs: dict = {}
_callers: dict = {}


def _stamp(path: Path):
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size, st.st_ino


def _caller(exp, options: dict | None):
    """`jax.jit(exp.call, compiler_options=options)`, one per program and options in a process:
    a program called again is neither deserialized nor lowered again."""
    import jax

    key = (id(exp), repr(sorted((options or {}).items())))
    hit = _callers.get(key)
    if hit is None or hit[0] is not exp:
        hit = _callers[key] = (exp, jax.jit(exp.call, compiler_options=options))
    return hit[1]


def _exported_program(fn, args: tuple):
    """`(Exported, array leaves)` for `fn(*args)`: read from disk when present and valid,
    else traced, exported and written. None where the key would not be stable."""
    import jax
    from jax import export

    treedef, static, is_array, arrays = split_arguments(args)
    key = export_key(fn, treedef, static, arrays)
    if key is None:
        return None
    name, digest = key
    path = Path(cache_dir()) / EXPORT_SUBDIR / f"{name}-{digest[:32]}.jaxexport"
    header = f"jthermo-export {digest}\n".encode()
    known = _programs.get(path)
    stamp = _stamp(path)
    if known is not None and stamp is not None and known[0] == stamp and known[1] == header:
        return known[2], arrays     # this process read or wrote this very file already
    exp = read_export(path, header, arrays)
    if exp is None:
        def flat(*xs):
            it = iter(xs)
            full = [next(it) if a else v for v, a in zip(static, is_array)]
            return fn(*jax.tree.unflatten(treedef, full))

        exp = export.export(jax.jit(flat))(*arrays)
        _write_atomic(path, header + exp.serialize())
    stamp = _stamp(path)
    if stamp is not None:
        _programs[path] = (stamp, header, exp)
    return exp, arrays


def split_arguments(args: tuple):
    """`(treedef, static leaves (None for an array), is-array flags, array leaves)` of `args`."""
    import jax

    leaves, treedef = jax.tree.flatten(args)
    is_array = [isinstance(v, jax.Array) or hasattr(v, "__array__") and hasattr(v, "dtype")
                for v in leaves]
    arrays = [v for v, a in zip(leaves, is_array) if a]
    static = [None if a else v for v, a in zip(leaves, is_array)]
    return treedef, static, is_array, arrays


def export_key(fn, treedef, static, arrays, extra: str = "") -> tuple[str, str] | None:
    """`(file name stem, SHA-256 of the key text)`, or None where the key would not be stable.
    `extra` joins the key text (the arrays' bytes, for `cached_arrays`)."""
    import hashlib

    import jax

    flags = [f"{k}={getattr(jax.config, k, None)}" for k in _TRACE_FLAGS]
    parts = [_EXPORT_FORMAT, f"{fn.__module__}.{fn.__qualname__}", _source_hash(),
             _versions(), " ".join(flags), lowering_tags(),
             jax.default_backend(), str(treedef), repr(static),
             repr([(tuple(a.shape), str(a.dtype), bool(getattr(a, "weak_type", False)))
                   for a in arrays]), extra]
    text = "\n".join(parts)
    if " at 0x" in text:   # an object repr with its address: a key no other process makes
        return None
    name = "".join(c if c.isalnum() else "_" for c in fn.__qualname__)[:40]
    return name, hashlib.sha256(text.encode()).hexdigest()


@functools.cache
def _source_hash() -> str:
    """SHA-256 of every `.py` file of the jthermo package (path and content)."""
    import hashlib

    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()


@functools.cache
def _versions() -> str:
    """The versions of the packages that shape a traced program (their `__version__`, else
    where they are installed; `importlib.metadata` costs ~50 ms)."""
    import importlib

    out = []
    for name in ("jax", "jaxlib", "equinox", "numpy"):
        mod = importlib.import_module(name)
        out.append(f"{name}={getattr(mod, '__version__', None) or mod.__file__}")
    return " ".join(out)


def read_export(path: Path, header: bytes, arrays):
    """The `Exported` in `path` when it starts with `header` (the full key: a file copied from
    another key is refused), deserializes and takes `arrays`, else None."""
    from jax import export

    try:
        blob = path.read_bytes()
    except OSError:
        return None
    if not blob.startswith(header):
        return None
    try:
        exp = export.deserialize(bytearray(blob[len(header):]))
        ok = len(exp.in_avals) == len(arrays) and all(
            tuple(a.shape) == tuple(b.shape) and a.dtype == b.dtype
            for a, b in zip(exp.in_avals, arrays))
    except Exception:  # noqa: BLE001  (a corrupt or foreign file)
        return None
    if not ok:
        return None
    try:
        os.utime(path)    # recently used: kept by `_prune`
    except OSError:
        pass
    return exp


def _write_atomic(path: Path, blob: bytes) -> None:
    """Write `blob` to `path` by a rename (concurrent readers see the old file or the new
    one); then keep the `MAX_EXPORTS` most recently used files. Failures are ignored."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            f.write(blob)
        os.replace(tmp, path)
        tmp = None
        _prune(path.parent, MAX_EXPORTS)
    except OSError:
        pass
    finally:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass


def _prune(folder: Path, keep: int) -> None:
    files = sorted([*folder.glob("*.jaxexport"), *folder.glob("*.npz")],
                   key=lambda p: p.stat().st_mtime, reverse=True)
    for p in files[keep:]:
        p.unlink(missing_ok=True)


# ---------------------------------------------------------------- numeric results kept on disk


def cached_arrays(fn, args: tuple, compute):
    """`compute(*args)`, a dict of arrays that is a deterministic function of `args` and
    jthermo's source (`fn` names it), kept in the cache directory (`EXPORT_SUBDIR`, `.npz`)
    so that a later process reads the numbers instead of loading and running a program.

    The key is `exported_call`'s (source hash, versions, trace settings, tree structure,
    static leaves, shapes and dtypes) plus a SHA-256 of every input array's bytes; the file
    holds the full key and the output's key names and dtypes, checked on read. Nothing is
    read or written with the cache off or inside a JAX trace; a file that is unreadable,
    corrupt or from another key is recomputed and rewritten (atomically, as `exported_call`).
    Never raises for the file itself; errors of `compute` propagate. Arrays come back as
    `jax.Array`s, equal bit for bit to what `compute` returned."""
    path = header = None
    if cache_dir() is not None and top_level():
        try:
            path, header = _arrays_path(fn, args)
        except Exception:  # noqa: BLE001  (a leaf that cannot be hashed: no file)
            path = None
    if path is not None:
        out = _read_arrays(path, header)
        if out is not None:
            return out
    out = compute(*args)
    if path is not None:
        try:
            _write_atomic(path, header + _npz_bytes(out))
        except Exception:  # noqa: BLE001  (an output that is not a dict of arrays)
            pass
    return out


def _arrays_path(fn, args: tuple):
    """`(path, header)` of `fn(*args)`'s `.npz` file, or `(None, None)` for an unstable key."""
    import hashlib

    import numpy as np

    treedef, static, _, arrays = split_arguments(args)
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(np.asarray(a)).tobytes())
    key = export_key(fn, treedef, static, arrays, extra="bytes " + h.hexdigest())
    if key is None:
        return None, None
    name, digest = key
    path = Path(cache_dir()) / EXPORT_SUBDIR / f"{name}-{digest[:32]}.npz"
    return path, f"jthermo-arrays {digest}\n".encode()


def _npz_bytes(out: dict) -> bytes:
    """`out` (str -> array) as `.npz` bytes, preceded by one line naming its keys and dtypes."""
    import io

    import numpy as np

    host = {str(k): np.asarray(v) for k, v in out.items()}
    buf = io.BytesIO()
    np.savez(buf, **host)
    return _layout(host).encode() + b"\n" + buf.getvalue()


def _layout(arrays: dict) -> str:
    return " ".join(f"{k}:{v.dtype.str}:{'x'.join(map(str, v.shape))}"
                    for k, v in arrays.items())


def _read_arrays(path: Path, header: bytes) -> dict | None:
    """The dict in `path` when it starts with `header` and its arrays match the layout line,
    as `jax.Array`s; else None."""
    import io

    import jax
    import numpy as np

    try:
        blob = path.read_bytes()
        if not blob.startswith(header):
            return None
        layout, _, data = blob[len(header):].partition(b"\n")
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            host = {k: z[k] for k in z.files}
        if _layout(host) != layout.decode():
            return None
    except Exception:  # noqa: BLE001  (unreadable, truncated or foreign)
        return None
    try:
        os.utime(path)    # recently used: kept by `_prune`
    except OSError:
        pass
    device = jax.devices()[0]   # committed, like a program's outputs (same eager programs)
    return {k: jax.device_put(v, device) for k, v in host.items()}
