"""Save and load models, controllers and fit results: one file, exact round trip.

A jthermo file is a zip archive with two members:

- `header.json`: format version, jthermo version, kind (`model`, `controller`, `fit_result`,
  `object`), the class (`module:qualname`), family, orders, units, sample time, user `meta`,
  and a *skeleton spec*: the object's tree of fields, with static values written out and each
  array leaf recorded by shape, dtype and kind (JAX or NumPy).
- `leaves.eqx`: the array leaves, written by `equinox.tree_serialise_leaves`.

Loading rebuilds the skeleton from the spec without calling any `__init__`
(`object.__new__(cls)` and the dataclass fields set directly), then fills its leaves with
`equinox.tree_deserialise_leaves`. Nothing is executed from the file: classes are only looked
up in trusted modules (`jthermo` by default). Writes are atomic (temporary file + rename).

The JSON reports of the command and the demo are written here too (`jsonable`, `write_json`).
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
import io
import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._files import atomic_write_bytes as atomic_write_bytes
from ._files import atomic_write_text
from .errors import ConfigError

#: bump on any change that old readers cannot follow
FORMAT_VERSION = 1
MAGIC = "jthermo-save"
TRUSTED_MODULES = ("jthermo",)

_HEADER = "header.json"
_LEAVES = "leaves.eqx"


# ---------------------------------------------------------------- skeleton spec


def _qualname(obj_or_cls: Any) -> str:
    cls = obj_or_cls if isinstance(obj_or_cls, type) else type(obj_or_cls)
    return f"{cls.__module__}:{cls.__qualname__}"


def _import(ref: str, trusted: tuple[str, ...]) -> Any:
    mod, _, qual = ref.partition(":")
    if not mod or not qual:
        raise ConfigError(f"saved file names an invalid class reference {ref!r}")
    if not any(mod == t or mod.startswith(t + ".") for t in trusted):
        raise ConfigError(
            f"saved file names class `{ref}` outside the trusted modules {', '.join(trusted)}")
    try:
        obj = importlib.import_module(mod)
        for part in qual.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError):
        raise ConfigError(f"saved file needs `{ref}`, which this jthermo does not have") from None
    return obj


def _fields_of(obj: Any) -> list[str]:
    return [f.name for f in dataclasses.fields(obj)]


def _spec(x: Any, leaves: list, path: str = "obj") -> Any:
    """A JSON description of `x` from which a skeleton with the same tree structure is rebuilt."""
    if x is None or isinstance(x, (bool, str)):
        return {"t": "const", "v": x}
    if isinstance(x, enum.Enum):
        return {"t": "enum", "cls": _qualname(x), "v": x.name}
    if isinstance(x, int):
        return {"t": "int", "v": x}
    if isinstance(x, float):
        return {"t": "float", "v": repr(x)}  # repr keeps inf/nan and every bit
    if isinstance(x, complex):
        return {"t": "complex", "v": [repr(x.real), repr(x.imag)]}
    if isinstance(x, (np.ndarray, np.generic)):
        a = np.asarray(x)
        if a.dtype == object:
            raise ConfigError(f"cannot save `{path}`: object arrays are not supported")
        leaves.append(np.asarray(x))
        return {"t": "np" if isinstance(x, np.ndarray) else "npscalar", "shape": list(a.shape),
                "dtype": str(a.dtype), "i": len(leaves) - 1}
    if isinstance(x, jnp.ndarray):
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            raise ConfigError(f"cannot save `{path}`: PRNG key arrays are not supported")
        leaves.append(x)
        return {"t": "jax", "shape": list(x.shape), "dtype": str(x.dtype), "i": len(leaves) - 1}
    if isinstance(x, eqx.Module) or (dataclasses.is_dataclass(x) and not isinstance(x, type)):
        return {"t": "dataclass", "cls": _qualname(x),
                "fields": {name: _spec(getattr(x, name), leaves, f"{path}.{name}") for name in _fields_of(x)}}
    if isinstance(x, tuple) and hasattr(x, "_fields"):  # NamedTuple
        return {"t": "namedtuple", "cls": _qualname(x),
                "items": [_spec(v, leaves, f"{path}.{k}") for k, v in zip(x._fields, x)]}
    if isinstance(x, (tuple, list)):
        return {"t": type(x).__name__, "items": [_spec(v, leaves, f"{path}[{i}]") for i, v in enumerate(x)]}
    if isinstance(x, dict):
        if not all(isinstance(k, str) for k in x):
            raise ConfigError(f"cannot save `{path}`: dict keys must be strings")
        return {"t": "dict", "items": {k: _spec(v, leaves, f"{path}[{k!r}]") for k, v in x.items()}}
    if callable(x) and getattr(x, "__module__", None) and getattr(x, "__qualname__", None) \
            and "<" not in x.__qualname__:
        return {"t": "ref", "v": f"{x.__module__}:{x.__qualname__}"}
    raise ConfigError(f"cannot save `{path}`: unsupported value of type {type(x).__name__}")


def _float(s: str) -> float:
    return float(s)


def _leaf_specs(spec: Any, out: list) -> list:
    """The array-leaf specs of a skeleton spec, in the order they were serialised."""
    if isinstance(spec, dict):
        if spec.get("t") in ("np", "npscalar", "jax"):
            out.append(spec)
        else:
            for v in spec.values():
                _leaf_specs(v, out)
    elif isinstance(spec, list):
        for v in spec:
            _leaf_specs(v, out)
    return out


def _zeros_like_spec(spec: dict) -> Any:
    try:
        dtype = np.dtype(spec["dtype"])
        shape = tuple(int(n) for n in spec["shape"])
    except (TypeError, KeyError, ValueError):
        raise ConfigError("saved file has a malformed array description") from None
    a = np.zeros(shape, dtype)
    return jnp.asarray(a) if spec["t"] == "jax" else a


def _build(spec: Any, trusted: tuple[str, ...], arrays: list | None) -> Any:
    """Rebuild the object from its spec and its loaded array leaves (no `__init__` is run)."""
    try:
        t = spec["t"]
    except (TypeError, KeyError):
        raise ConfigError("saved file has a malformed skeleton spec") from None
    if t == "const":
        return spec["v"]
    if t == "int":
        return int(spec["v"])
    if t == "float":
        return _float(spec["v"])
    if t == "complex":
        return complex(_float(spec["v"][0]), _float(spec["v"][1]))
    if t == "enum":
        return getattr(_import(spec["cls"], trusted), spec["v"])
    if t in ("np", "npscalar", "jax"):
        if arrays is None:  # structure check only
            return None
        try:
            a = arrays[int(spec["i"])]
        except (KeyError, IndexError, TypeError, ValueError):
            raise ConfigError("saved file has a malformed array index") from None
        if t == "np":
            return np.asarray(a)
        if t == "npscalar":
            return np.asarray(a)[()]
        return a
    if t == "dataclass":
        cls = _import(spec["cls"], trusted)
        if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
            raise ConfigError(f"saved file names `{spec['cls']}`, which is not a dataclass or Module")
        obj = object.__new__(cls)
        names = {f.name for f in dataclasses.fields(cls)}
        # fields added since the file was written take their defaults (older files load)
        for f in dataclasses.fields(cls):
            if f.name not in spec["fields"] and f.default is not dataclasses.MISSING:
                object.__setattr__(obj, f.name, f.default)
                names.discard(f.name)
        if set(spec["fields"]) != names:
            raise ConfigError(
                f"saved `{spec['cls']}` has fields {sorted(spec['fields'])}, this jthermo has "
                f"{sorted(names)}: incompatible version")
        for name, sub in spec["fields"].items():
            object.__setattr__(obj, name, _build(sub, trusted, arrays))
        return obj
    if t == "namedtuple":
        cls = _import(spec["cls"], trusted)
        return cls(*[_build(s, trusted, arrays) for s in spec["items"]])
    if t == "tuple":
        return tuple(_build(s, trusted, arrays) for s in spec["items"])
    if t == "list":
        return [_build(s, trusted, arrays) for s in spec["items"]]
    if t == "dict":
        return {k: _build(s, trusted, arrays) for k, s in spec["items"].items()}
    if t == "ref":
        return _import(spec["v"], trusted)
    raise ConfigError(f"saved file has an unknown node type {t!r}")


# ---------------------------------------------------------------- header


def _kind_of(obj: Any) -> str:
    from .control._base import AbstractController
    from .models._base import AbstractModel

    if isinstance(obj, AbstractModel):
        return "model"
    if isinstance(obj, AbstractController):
        return "controller"
    model = getattr(obj, "model", None)
    if isinstance(model, AbstractModel) and hasattr(obj, "family"):
        return "fit_result"
    return "object"


def _header_value(x: Any) -> Any:
    """A header field as JSON: arrays become lists, other objects their `str` (NaN kept, so
    `save` refuses it)."""
    if isinstance(x, dict):
        return {str(k): _header_value(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_header_value(v) for v in x]
    if isinstance(x, (np.generic, jnp.ndarray, np.ndarray)):
        a = np.asarray(x)
        return a.item() if a.ndim == 0 else a.tolist()
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    return str(x)


def _describe(obj: Any, kind: str, meta: dict) -> dict:
    """Family, orders, sizes and units for the header (informative; not needed to load).

    `meta["family"]` / `meta["orders"]` name them where the object itself does not."""
    from .models._base import AbstractModel

    target = obj.model if kind == "fit_result" else obj
    family = getattr(obj, "family", None)
    info: dict[str, Any] = {"family": meta.get("family") or (family if isinstance(family, str) and family
                                                             else type(target).__name__.lower())}
    orders = meta.get("orders", getattr(obj, "orders", None))
    if orders is None and hasattr(target, "orders"):
        orders = getattr(target, "orders")
    if callable(orders):
        orders = None
    if orders is not None:
        info["orders"] = _header_value(orders)
    if isinstance(target, AbstractModel):
        try:
            ss = target.to_statespace()
            info.update(ts=float(ss.ts), n_inputs=int(ss.B.shape[1]), n_outputs=int(ss.C.shape[0]),
                        n_signals=int(ss.Bw.shape[1]), n_states=int(ss.A.shape[0]))
        except Exception:  # a model that cannot convert still saves
            pass
        info["units"] = {"t": "s", "u": "power fraction [0, 1]", "w": "°C", "y": "°C"}
    elif kind == "controller":
        ts = getattr(obj, "ts", None)
        if isinstance(ts, (int, float)):
            info["ts"] = float(ts)
        info["units"] = {"y": "°C", "r": "°C", "u": "power fraction [0, 1]"}
    return info


# ---------------------------------------------------------------- public API


def save(obj: Any, path: str | os.PathLike, *, meta: dict | None = None) -> Path:
    """Save a model, controller or fit result (any equinox Module / dataclass tree) to `path`.

    **Arguments:**
    - `obj`: an `AbstractModel`, `AbstractController`, a FitResult-like object or any tree of
      equinox Modules, dataclasses, tuples, lists, dicts, arrays and Python scalars.
    - `path`: the file to write (atomically). By convention `.jtm`.
    - `meta`: free JSON-serialisable information stored in the header (data file, seed, ...).

    **Returns:** the path written.
    """
    from . import __version__

    kind = _kind_of(obj)
    arrays: list = []
    spec = _spec(obj, arrays)
    header = {"magic": MAGIC, "format_version": FORMAT_VERSION, "jthermo_version": __version__,
              "kind": kind, "class": _qualname(obj), **_describe(obj, kind, meta or {}),
              "meta": _header_value(meta or {}), "spec": spec}
    try:
        header_text = json.dumps(header, indent=1, allow_nan=False)
    except ValueError as exc:
        raise ConfigError(f"cannot save: header is not JSON-serialisable ({exc})") from None
    leaves = io.BytesIO()
    eqx.tree_serialise_leaves(leaves, arrays)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr(_HEADER, header_text)
        z.writestr(_LEAVES, leaves.getvalue())
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


def _open(path: str | os.PathLike) -> tuple[dict, bytes]:
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{p}: no such file")
    if p.is_dir():
        raise ConfigError(f"{p}: is a directory, not a saved jthermo file")
    try:
        with zipfile.ZipFile(p) as z:
            names = set(z.namelist())
            if _HEADER not in names or _LEAVES not in names:
                raise ConfigError(f"{p}: not a jthermo save file (missing {_HEADER} or {_LEAVES})")
            header_bytes = z.read(_HEADER)
            leaves = z.read(_LEAVES)
    except ConfigError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError,
            RuntimeError, NotImplementedError) as exc:
        raise ConfigError(f"{p}: not a jthermo save file, or truncated/corrupt ({type(exc).__name__})") from None
    try:
        header = json.loads(header_bytes.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise ConfigError(f"{p}: corrupt header (not JSON)") from None
    if not isinstance(header, dict) or header.get("magic") != MAGIC:
        raise ConfigError(f"{p}: not a jthermo save file (bad magic)")
    version = header.get("format_version")
    if version != FORMAT_VERSION:
        raise ConfigError(
            f"{p}: saved with file format version {version!r} (jthermo {header.get('jthermo_version')}); "
            f"this jthermo reads version {FORMAT_VERSION}")
    return header, leaves


def load_header(path: str | os.PathLike) -> dict:
    """The JSON header of a saved file (kind, class, family, orders, units, meta, ...)."""
    header, _ = _open(path)
    return header


def load(path: str | os.PathLike, *, kind: str | None = None,
         trusted_modules: tuple[str, ...] = TRUSTED_MODULES) -> Any:
    """Load what `save` wrote; the loaded object predicts bit-for-bit as the saved one.

    **Arguments:**
    - `path`: a file written by `save`.
    - `kind`: if given (`"model"`, `"controller"`, `"fit_result"`), refuse a file of another kind.
    - `trusted_modules`: module prefixes from which classes may be looked up.

    Raises `ConfigError` on a missing, truncated or corrupt file, an incompatible format
    version, a class this jthermo does not have, or the wrong kind.
    """
    header, leaves = _open(path)
    if kind is not None and header.get("kind") != kind:
        raise ConfigError(f"{path}: holds a {header.get('kind')} ({header.get('class')}), not a {kind}")
    spec = header.get("spec")
    _build(spec, tuple(trusted_modules), None)   # classes and fields first: clearer errors
    like = [_zeros_like_spec(a) for a in sorted(_leaf_specs(spec, []), key=lambda a: int(a["i"]))]
    try:
        arrays = eqx.tree_deserialise_leaves(io.BytesIO(leaves), like)
    except Exception as exc:  # numpy raises several types on a damaged payload
        raise ConfigError(f"{path}: corrupt or truncated array payload ({type(exc).__name__})") from None
    for a, b in zip(arrays, like):
        if np.shape(a) != np.shape(b) or a.dtype != b.dtype:
            raise ConfigError(f"{path}: array payload does not match its header")
    return _build(spec, tuple(trusted_modules), arrays)


def load_model(path: str | os.PathLike, *, trusted_modules: tuple[str, ...] = TRUSTED_MODULES):
    """Load a saved model; a saved fit result gives its `.model`."""
    header = load_header(path)
    if header.get("kind") == "fit_result":
        return load(path, trusted_modules=trusted_modules).model
    return load(path, kind="model", trusted_modules=trusted_modules)


def load_envelope(path: str | os.PathLike):
    """The recording's `models.Envelope` stored with a saved model (`jthermo fit --out`) or fit
    result, or None for a file written without one (before envelopes, or by hand)."""
    from .models.envelope import Envelope

    header = load_header(path)
    env = (header.get("meta") or {}).get("envelope")
    if env is None and header.get("kind") == "fit_result":
        return getattr(load(path), "envelope", None)
    return None if env is None else Envelope.from_dict(env)


def load_controller(path: str | os.PathLike, *,
                    trusted_modules: tuple[str, ...] = TRUSTED_MODULES):
    """Load a saved controller (`ConfigError` if the file holds something else)."""
    return load(path, kind="controller", trusted_modules=trusted_modules)


# ---------------------------------------------------------------- JSON reports


def jsonable(x: Any) -> Any:
    """Plain JSON types: arrays become lists, NaN/inf become null, other objects their name."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if isinstance(x, int):
        return x
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if hasattr(x, "__array__") and not callable(getattr(x, "step", None)):
        try:
            a = np.asarray(x)
        except Exception:  # noqa: BLE001 - an array-like that refuses is named by its str
            return str(x)
        if a.dtype.kind in "biuf":
            if a.ndim == 0:
                return jsonable(a.item())
            return jsonable(a.tolist())
        if a.dtype.kind == "c":
            return jsonable({"re": a.real.tolist(), "im": a.imag.tolist()})
        return str(x)
    if isinstance(x, Path):
        return str(x)
    return type(x).__name__


def write_json(path: str | os.PathLike | None, report: dict) -> None:
    """Write `jsonable(report)` to `path` (atomically); nothing when `path` is None."""
    if path is None:
        return
    atomic_write_text(path, json.dumps(jsonable(report), indent=2, allow_nan=False) + "\n")
