"""Input/output data: loading, validation, pre-processing and splitting.

Files follow the contract of DESIGN.md: a header row, `t` in seconds, inputs `u_<name>`,
outputs `y_<name>`, other measured signals `w_<name>`. Data are checked once, here, and
every problem is a `DataError` with a one-line reason naming the column and row.
"""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path
from typing import Any

import equinox as eqx
import numpy as np

from ._files import atomic_write_text as atomic_write_text
from .errors import DataError
from .time_grid import JITTER_TOLERANCE as JITTER_TOLERANCE
from .time_grid import MAX_GAP_SAMPLES as MAX_GAP_SAMPLES
from .time_grid import uniform_time as _uniform_time

#: how far apart two sample times may be and still be the same (a logged record's median step
#: wanders ~0.2 % around its nominal Ts; a model at 1 s run on 2 s data is another system)
TS_TOLERANCE = 0.05
#: values larger than this in magnitude are refused as corrupt
MAX_ABS_VALUE = 1e9
MIN_SAMPLES = 10
#: time stamps larger than this (s) are refused (allows Unix epoch times, in s or ms)
MAX_ABS_TIME = 1e15


class IOData(eqx.Module):
    """One experiment: inputs, outputs and optional measured signals on a uniform time grid.

    **Fields:**
    - `u`: inputs, `(T, nu)`; on the printer a heater power fraction in [0, 1].
    - `y`: outputs, `(T, ny)`; on the printer sensor temperatures in °C.
    - `w`: other measured signals, `(T, nw)` (surroundings °C, set points, fan), possibly `nw = 0`.
    - `ts`: sample time in s. `t0`: time of the first sample in s.
    - names of each column (without the `u_`/`y_`/`w_` prefix) and free-text `notes` that say what
      the loader or a pre-processing step did (re-gridding, detrending, ...).
    """

    u: np.ndarray
    y: np.ndarray
    w: np.ndarray
    ts: float = eqx.field(static=True)
    t0: float = eqx.field(static=True, default=0.0)
    input_names: tuple[str, ...] = eqx.field(static=True, default=())
    output_names: tuple[str, ...] = eqx.field(static=True, default=())
    signal_names: tuple[str, ...] = eqx.field(static=True, default=())
    notes: tuple[str, ...] = eqx.field(static=True, default=())

    def __check_init__(self):
        for name, arr in (("u", self.u), ("y", self.y), ("w", self.w)):
            if np.ndim(arr) != 2:
                raise DataError(f"IOData: `{name}` must be a 2-D (T, n) array, got shape {np.shape(arr)}")
        if not (len(self.u) == len(self.y) == len(self.w)):
            raise DataError(
                f"IOData: unequal lengths u={len(self.u)}, y={len(self.y)}, w={len(self.w)}")
        if len(self.input_names) != self.u.shape[1] or len(self.output_names) != self.y.shape[1] \
                or len(self.signal_names) != self.w.shape[1]:
            raise DataError("IOData: the number of names does not match the number of columns")
        if not (math.isfinite(self.ts) and self.ts > 0):
            raise DataError(f"IOData: sample time must be positive, got {self.ts}")

    @property
    def n_samples(self) -> int:
        return int(self.y.shape[0])

    @property
    def n_inputs(self) -> int:
        return int(self.u.shape[1])

    @property
    def n_outputs(self) -> int:
        return int(self.y.shape[1])

    @property
    def t(self) -> np.ndarray:
        """Time stamps in s, `(T,)`."""
        return self.t0 + self.ts * np.arange(self.n_samples)

    def replace(self, **changes: Any) -> "IOData":
        fields = {f: getattr(self, f) for f in ("u", "y", "w", "ts", "t0", "input_names",
                                                "output_names", "signal_names", "notes")}
        fields.update(changes)
        return IOData(**fields)

    def __len__(self) -> int:
        return self.n_samples


# ---------------------------------------------------------------- construction


def same_ts(a: float, b: float) -> bool:
    """Whether sample times `a` and `b` (s) agree: |a/b - 1| <= `TS_TOLERANCE`."""
    return abs(float(a) / float(b) - 1.0) <= TS_TOLERANCE


def from_arrays(u, y, ts: float = 1.0, w=None, *, input_names=None, output_names=None,
                signal_names=None, t0: float = 0.0, notes=()) -> IOData:
    """Build validated `IOData` from arrays `u (T, nu)`, `y (T, ny)` and optional `w (T, nw)`.

    1-D arrays are taken as a single column. Raises `DataError` on NaN/inf, unequal lengths,
    fewer than `MIN_SAMPLES` samples or absurd magnitudes.
    """
    cols = {}
    for name, arr in (("u", u), ("y", y), ("w", w)):
        if arr is None:
            continue
        try:
            a = np.asarray(arr, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise DataError(f"IOData: `{name}` is not numeric ({exc})") from None
        if a.ndim == 1:
            a = a[:, None]
        if a.ndim != 2:
            raise DataError(f"IOData: `{name}` must be 1-D or 2-D, got {a.ndim}-D")
        cols[name] = a
    if "u" not in cols or "y" not in cols:
        raise DataError("IOData: both inputs `u` and outputs `y` are required")
    T = cols["y"].shape[0]
    if "w" not in cols:
        cols["w"] = np.zeros((T, 0))
    lengths = {k: v.shape[0] for k, v in cols.items() if v.shape[1] > 0 or k != "w"}
    if len(set(lengths.values())) > 1:
        raise DataError(f"IOData: unequal lengths {lengths}")
    names = {
        "u": tuple(input_names) if input_names is not None else tuple(f"{i + 1}" for i in range(cols["u"].shape[1])),
        "y": tuple(output_names) if output_names is not None else tuple(f"{i + 1}" for i in range(cols["y"].shape[1])),
        "w": tuple(signal_names) if signal_names is not None else tuple(f"{i + 1}" for i in range(cols["w"].shape[1])),
    }
    for k, a in cols.items():
        if a.shape[1] != len(names[k]):
            raise DataError(f"IOData: {a.shape[1]} columns in `{k}` but {len(names[k])} names")
        _check_finite(a, [f"{k}_{n}" for n in names[k]])
    if T < MIN_SAMPLES:
        raise DataError(f"IOData: only {T} samples; at least {MIN_SAMPLES} are needed")
    return IOData(u=cols["u"], y=cols["y"], w=cols["w"], ts=float(ts), t0=float(t0),
                  input_names=names["u"], output_names=names["y"], signal_names=names["w"],
                  notes=tuple(notes))


def _check_finite(a: np.ndarray, colnames: list[str], row_offset: int = 0,
                  max_abs: float = MAX_ABS_VALUE, source: str = "IOData") -> None:
    bad = ~np.isfinite(a)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        what = "NaN" if np.isnan(a[r, c]) else "inf"
        raise DataError(f"{source}: column `{colnames[c]}` has {what} at row {r + 1 + row_offset}")
    big = np.abs(a) > max_abs
    if big.any():
        r, c = np.argwhere(big)[0]
        raise DataError(
            f"{source}: column `{colnames[c]}` has an implausible value {a[r, c]:.3g} at row {r + 1 + row_offset}")


def from_columns(columns: dict[str, np.ndarray], *, source: str = "data",
                 jitter_tolerance: float = JITTER_TOLERANCE, row_offset: int = 0) -> IOData:
    """Build `IOData` from named columns (`t`, `u_*`, `y_*`, `w_*`), checking the time axis.

    Logged time stamps with jitter (steps within `jitter_tolerance`·Ts of whole sample times), a
    dropped sample (a gap of up to `MAX_GAP_SAMPLES` steps), or a few isolated late or displaced
    stamps (`time_grid._off_grid`) are re-gridded onto a uniform grid by linear interpolation, and the
    returned `notes` say what was repaired. Anything else is refused. Rows in
    messages count samples from 1, plus `row_offset` (1 for a file with a header row).
    """
    if "t" not in columns:
        raise DataError(f"{source}: missing column `t` (time in seconds)")
    unknown = [c for c in columns if c != "t" and not c.startswith(("u_", "y_", "w_"))]
    if unknown:
        raise DataError(f"{source}: unknown column `{unknown[0]}` (expected t, u_*, y_*, w_*)")
    ucols = [c for c in columns if c.startswith("u_")]
    ycols = [c for c in columns if c.startswith("y_")]
    wcols = [c for c in columns if c.startswith("w_")]
    if not ucols:
        raise DataError(f"{source}: no input column (u_<name>)")
    if not ycols:
        raise DataError(f"{source}: no output column (y_<name>)")
    for c in columns:
        if c in ("u_", "y_", "w_"):
            raise DataError(f"{source}: column `{c}` has no name after its prefix")
    order = ["t"] + ucols + ycols + wcols
    arrays = []
    for c in order:
        try:
            a = np.asarray(columns[c], dtype=np.float64)
        except (TypeError, ValueError):
            raise DataError(f"{source}: column `{c}` is not numeric") from None
        if a.ndim != 1:
            raise DataError(f"{source}: column `{c}` must be one-dimensional, got shape {a.shape}")
        arrays.append(a)
    lengths = {len(a) for a in arrays}
    if len(lengths) > 1:
        raise DataError(f"{source}: columns have unequal lengths {sorted(lengths)}")
    mat = np.column_stack(arrays)
    t = mat[:, 0]
    # time stamps may be large (Unix epoch); only the signals get the magnitude check
    _check_finite(t[:, None], ["t"], row_offset, max_abs=MAX_ABS_TIME, source=source)
    _check_finite(mat[:, 1:], order[1:], row_offset, source=source)
    if len(t) < MIN_SAMPLES:
        raise DataError(f"{source}: only {len(t)} samples; at least {MIN_SAMPLES} are needed")
    t, mat, notes = _uniform_time(t, mat, source, jitter_tolerance, row_offset)
    nu, ny = len(ucols), len(ycols)
    ts = float(t[1] - t[0])
    return IOData(u=mat[:, 1:1 + nu], y=mat[:, 1 + nu:1 + nu + ny], w=mat[:, 1 + nu + ny:],
                  ts=ts, t0=float(t[0]), input_names=tuple(c[2:] for c in ucols),
                  output_names=tuple(c[2:] for c in ycols), signal_names=tuple(c[2:] for c in wcols),
                  notes=tuple(notes))


def _parse_csv_text(text: str, source: str) -> dict[str, np.ndarray]:
    if "\x00" in text:
        raise DataError(f"{source}: not a text CSV file (binary content)")
    rows = list(csv.reader(io.StringIO(text)))
    rows = [r for r in rows if r and any(cell.strip() for cell in r)]
    if not rows:
        raise DataError(f"{source}: empty file")
    header = [h.strip() for h in rows[0]]
    if len(set(header)) != len(header):
        dup = next(h for h in header if header.count(h) > 1)
        raise DataError(f"{source}: column `{dup}` appears twice in the header")
    if any(h == "" for h in header):
        raise DataError(f"{source}: empty column name in the header")
    if "t" not in header:
        raise DataError(f"{source}: header has no `t` column (expected t, u_*, y_*, w_*): {','.join(header)[:80]}")
    body = rows[1:]
    if not body:
        raise DataError(f"{source}: header only, no data rows")
    values = np.empty((len(body), len(header)))
    for i, row in enumerate(body):
        if len(row) != len(header):
            raise DataError(f"{source}: row {i + 2} has {len(row)} fields, the header has {len(header)}")
        for j, cell in enumerate(row):
            try:
                values[i, j] = float(cell)
            except ValueError:
                raise DataError(
                    f"{source}: column `{header[j]}` has non-numeric value {cell.strip()[:20]!r} at row {i + 2}"
                ) from None
    return {h: values[:, j] for j, h in enumerate(header)}


def load_csv(path: str | os.PathLike, **kwargs) -> IOData:
    """Load a CSV file with columns `t`, `u_*`, `y_*`, `w_*` into validated `IOData`."""
    p = Path(path)
    if not p.exists():
        raise DataError(f"{p}: no such file")
    if p.is_dir():
        raise DataError(f"{p}: is a directory, not a data file")
    raw = p.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise DataError(f"{p}: not a text CSV file (binary or non-UTF-8 content)") from None
    # rows in messages are file lines (the header is row 1)
    return from_columns(_parse_csv_text(text, str(p)), source=str(p), row_offset=1, **kwargs)


def from_dataframe(df, *, source: str = "DataFrame", **kwargs) -> IOData:
    """Build `IOData` from a pandas DataFrame whose columns follow the file contract."""
    cols = {}
    for c in df.columns:
        try:
            cols[str(c)] = np.asarray(df[c], dtype=np.float64)
        except (TypeError, ValueError):
            raise DataError(f"{source}: column `{c}` is not numeric") from None
    return from_columns(cols, source=source, **kwargs)


def load(path: str | os.PathLike, **kwargs) -> IOData:
    """Load `.csv`, `.parquet` or `.npz` (arrays named by column) into validated `IOData`."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".parquet":
        if not p.exists():
            raise DataError(f"{p}: no such file")
        import pandas as pd
        try:
            df = pd.read_parquet(p)
        except Exception as exc:  # pyarrow raises many types on corrupt files
            raise DataError(f"{p}: not a readable Parquet file ({type(exc).__name__})") from None
        return from_dataframe(df, source=str(p), **kwargs)
    if suffix == ".npz":
        if not p.exists():
            raise DataError(f"{p}: no such file")
        try:
            with np.load(p, allow_pickle=False) as z:
                cols = {k: z[k] for k in z.files}
        except Exception as exc:
            raise DataError(f"{p}: not a readable .npz file ({type(exc).__name__})") from None
        return from_columns(cols, source=str(p), **kwargs)
    return load_csv(p, **kwargs)


def to_columns(data: IOData) -> dict[str, np.ndarray]:
    cols = {"t": data.t}
    for prefix, names, arr in (("u_", data.input_names, data.u), ("y_", data.output_names, data.y),
                               ("w_", data.signal_names, data.w)):
        for j, n in enumerate(names):
            cols[prefix + n] = arr[:, j]
    return cols


def save_csv(data: IOData, path: str | os.PathLike) -> None:
    """Write `data` in the CSV contract (atomically)."""
    cols = to_columns(data)
    header = ",".join(cols)
    mat = np.column_stack(list(cols.values()))
    buf = io.StringIO()
    buf.write(header + "\n")
    np.savetxt(buf, mat, delimiter=",", fmt="%.10g")
    atomic_write_text(path, buf.getvalue())


# ---------------------------------------------------------------- checks


def idle_inputs(data: IOData, *, rel_tol: float = 1e-9) -> list[int]:
    """Indices of the input columns constant over the record (to `rel_tol` of their magnitude):
    e.g. a logged heater that was never switched on."""
    u = np.asarray(data.u)
    return [j for j in range(u.shape[1])
            if np.ptp(u[:, j]) <= rel_tol * max(1.0, float(np.abs(u[:, j]).max()))]


def require_excitation(data: IOData, *, rel_tol: float = 1e-9) -> None:
    """Raise `DataError` if an input column is constant: it cannot excite the system."""
    idle = idle_inputs(data, rel_tol=rel_tol)
    if idle:
        j = idle[0]
        raise DataError(f"IOData: input `u_{data.input_names[j]}` is constant ({data.u[0, j]:g}): "
                        "it cannot excite the system")


def keep_outputs(data: IOData, names, what: str = "data") -> IOData:
    """`data` with only the outputs `names` (with or without the `y_` prefix), in that order
    (e.g. the sensor of the heated zone of a one-heater device that logs two)."""
    names = [str(n)[2:] if str(n).startswith("y_") else str(n) for n in names]
    missing = [n for n in names if n not in data.output_names]
    if missing or not names or len(set(names)) < len(names):
        raise DataError(f"{what}: " + (f"no output `y_{missing[0]}`" if missing else
                                       "the outputs to keep must be distinct and at least one")
                        + f" (its outputs: {', '.join('y_' + n for n in data.output_names)})")
    keep = [data.output_names.index(n) for n in names]
    return data.replace(y=np.asarray(data.y)[:, keep], output_names=tuple(names))


def keep_inputs(data: IOData, names, what: str = "data") -> IOData:
    """`data` with only the inputs `names` (without the `u_` prefix), in that order; the others
    must be constant in it (a model without them cannot follow their effect), else `DataError`."""
    names = [str(n) for n in names]
    missing = [n for n in names if n not in data.input_names]
    if missing:
        raise DataError(f"{what}: no input `u_{missing[0]}` (its inputs: "
                        f"{', '.join('u_' + n for n in data.input_names)})")
    idle = set(idle_inputs(data))
    for j, n in enumerate(data.input_names):
        if n not in names and j not in idle:
            raise DataError(f"{what}: input `u_{n}` varies in this record, but the model has no "
                            "such input (it was constant, and left out, in the estimation record)")
    keep = [data.input_names.index(n) for n in names]
    return data.replace(u=np.asarray(data.u)[:, keep], input_names=tuple(names))


def require_output_variation(data: IOData, what: str = "IOData", *,
                             rel_tol: float = 1e-9) -> None:
    """Raise `DataError` if an output column is constant (to `rel_tol` of its magnitude): there is
    nothing to identify or explain, and its fit % (a ratio to its variation) is undefined."""
    for j, name in enumerate(data.output_names):
        col = np.asarray(data.y[:, j])
        if np.ptp(col) <= rel_tol * max(1.0, float(np.abs(col).max())):
            raise DataError(f"{what}: output `y_{name}` is constant ({col[0]:g}): nothing to "
                            "identify")


def require_samples(data: IOData, n_params: int, what: str = "model") -> None:
    """Raise `DataError` if there are fewer samples (per output) than parameters to estimate."""
    if data.n_samples <= n_params:
        raise DataError(
            f"IOData: {data.n_samples} samples are too few for a {what} with {n_params} parameters per output")


# ---------------------------------------------------------------- pre-processing


def crop(data: IOData, start: float | None = None, stop: float | None = None, *,
         unit: str = "samples") -> IOData:
    """Keep samples `start <= k < stop` (or times in s with `unit="s"`)."""
    if unit == "s":
        start = None if start is None else int(round((start - data.t0) / data.ts))
        stop = None if stop is None else int(round((stop - data.t0) / data.ts))
    sl = slice(start, stop)
    k0 = range(data.n_samples)[sl]
    if len(k0) < MIN_SAMPLES:
        raise DataError(f"crop: only {len(k0)} samples left; at least {MIN_SAMPLES} are needed")
    return data.replace(u=data.u[sl], y=data.y[sl], w=data.w[sl], t0=data.t0 + data.ts * k0.start,
                        notes=data.notes + (f"cropped to samples {k0.start}..{k0.stop - 1}",))


def detrend(data: IOData, kind: str = "mean", *, inputs: bool = True) -> IOData:
    """Remove the mean (`kind="mean"`) or a least-squares line (`"linear"`) from y (and u)."""
    if kind not in ("mean", "linear"):
        raise DataError(f"detrend: kind must be 'mean' or 'linear', got {kind!r}")

    def _do(a):
        if kind == "mean":
            return a - a.mean(axis=0)
        k = np.arange(len(a), dtype=np.float64)
        X = np.column_stack([np.ones_like(k), k])
        coef, *_ = np.linalg.lstsq(X, a, rcond=None)
        return a - X @ coef

    return data.replace(y=_do(data.y), u=_do(data.u) if inputs else data.u,
                        notes=data.notes + (f"detrended ({kind})",))


def highpass(data: IOData, cutoff_hz: float, order: int = 2, *, inputs: bool = True) -> IOData:
    """Zero-phase Butterworth high-pass (forward-backward filtering) of y (and u).

    $H(s)$ of the given order with corner `cutoff_hz`; applied with `scipy.signal.sosfiltfilt`
    so the pass band has no phase shift (the thesis removed slow drift this way, §3.1).
    """
    from scipy import signal

    nyq = 0.5 / data.ts
    if not (0 < cutoff_hz < nyq):
        raise DataError(f"highpass: cutoff {cutoff_hz:g} Hz must lie in (0, {nyq:g}) Hz")
    sos = signal.butter(order, cutoff_hz / nyq, btype="highpass", output="sos")
    if data.n_samples <= 3 * (2 * len(sos) + 1):
        raise DataError("highpass: too few samples for zero-phase filtering")
    f = lambda a: signal.sosfiltfilt(sos, a, axis=0)  # noqa: E731
    return data.replace(y=f(data.y), u=f(data.u) if inputs else data.u,
                        notes=data.notes + (f"high-pass {cutoff_hz:g} Hz (order {order}, zero-phase)",))


def split(data: IOData, fraction: float = 0.5) -> tuple[IOData, IOData]:
    """Estimation/validation split: the first `fraction` of the samples, then the rest."""
    if not 0 < fraction < 1:
        raise DataError(f"split: fraction must lie in (0, 1), got {fraction}")
    k = int(round(fraction * data.n_samples))
    return crop(data, 0, k), crop(data, k, None)
