"""Figures: compare, residual tests, Bode, steps, pole-zero map, closed loop, tuning, bed heat-map.

Every function builds a `matplotlib.figure.Figure` directly (no pyplot, no global state, works
headless), returns it, and writes it to `path` when one is given (atomically: a temporary file,
then a rename). Together with `report.py` this is the only module that imports matplotlib.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ._files import atomic_write
from .errors import DataError

__all__ = [
    "plot_bed_heatmap",
    "plot_bode",
    "plot_closed_loop",
    "plot_compare",
    "plot_pzmap",
    "plot_residual_tests",
    "plot_residuals",
    "plot_step",
    "plot_tuning_curve",
    "save_figure",
]

#: at most this many output rows / input columns are drawn in grid figures
MAX_PANELS = 4


def save_figure(fig: Figure, path: str | os.PathLike, dpi: int = 110) -> Path:
    """Write `fig` to `path` (format from the suffix, PNG by default) through a temporary file."""
    fmt = Path(path).suffix.lstrip(".").lower() or "png"
    return atomic_write(path, lambda tmp: fig.savefig(tmp, format=fmt, dpi=dpi, bbox_inches="tight"))


def _finish(fig, path):
    if path is not None:
        save_figure(fig, path)
    return fig


def _as_2d(a, name):
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(f"plot: `{name}` must be (T,) or (T, n), got shape {a.shape}")
    return a


def _models_dict(models):
    if isinstance(models, dict):
        return dict(models)
    if isinstance(models, (list, tuple)):
        return {f"model {i + 1}": m for i, m in enumerate(models)}
    return {type(models).__name__: models}


def _grid(fig, nrows, ncols, **kw):
    axes = fig.subplots(nrows, ncols, squeeze=False, **kw)
    return axes


def _channels(ny, nu, channels):
    if channels is not None:
        return [tuple(c) for c in channels]
    if ny * nu <= MAX_PANELS * MAX_PANELS and max(ny, nu) <= MAX_PANELS:
        return [(i, j) for i in range(ny) for j in range(nu)]
    return [(i, i) for i in range(min(ny, nu, MAX_PANELS))]


# ---------------------------------------------------------------- identification


def plot_compare(data, yhat: dict, fits: dict | None = None, *, outputs=None,
                 path: str | os.PathLike | None = None) -> Figure:
    """Measured outputs against model outputs, one panel per output, fit % in the legend.

    **Arguments:** `data` (IOData); `yhat` name → `(T, ny)` model output; `fits` name →
    fit % per output (e.g. `compare(...)["fit_percent"]`); `outputs` indices to draw
    (default: the first four).
    """
    y = _as_2d(data.y, "data.y")
    t = data.t
    ny = y.shape[1]
    outs = list(range(min(ny, MAX_PANELS))) if outputs is None else list(outputs)
    fig = Figure(figsize=(9, 2.2 * len(outs) + 0.6), layout="constrained")
    axes = _grid(fig, len(outs), 1, sharex=True)[:, 0]
    names = data.output_names
    for ax, i in zip(axes, outs):
        ax.plot(t, y[:, i], color="k", lw=1.0, label="measured")
        for name, yh in yhat.items():
            yh = _as_2d(yh, f"yhat[{name!r}]")
            if yh.shape != y.shape:
                raise DataError(f"plot_compare: `{name}` has shape {yh.shape}, the data {y.shape}")
            label = name if fits is None or name not in fits else f"{name}: {np.ravel(fits[name])[i]:.1f} %"
            ax.plot(t, yh[:, i], lw=1.0, label=label)
        ax.set_ylabel(f"y_{names[i]}")
        ax.legend(loc="upper right", fontsize="small")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle("Measured and simulated outputs (fit %)")
    return _finish(fig, path)


def plot_residual_tests(result: dict, *, outputs=None, path: str | os.PathLike | None = None) -> Figure:
    """Residual auto-correlation and residual–input cross-correlations with the confidence band.

    `result` is the dict of `validate.residual_tests`. One row per output: left the
    auto-correlation, right the cross-correlation with every input (one line each).
    """
    auto = np.asarray(result["auto"])
    cross = np.asarray(result["cross"])
    la, lc, b = result["lags_auto"], result["lags_cross"], float(result["bound"])
    ny, nu = cross.shape[1], cross.shape[2]
    outs = list(range(min(ny, MAX_PANELS))) if outputs is None else list(outputs)
    onames = result.get("output_names") or tuple(str(i + 1) for i in range(ny))
    inames = result.get("input_names") or tuple(str(j + 1) for j in range(nu))
    fig = Figure(figsize=(10, 2.2 * len(outs) + 0.6), layout="constrained")
    axes = _grid(fig, len(outs), 2)
    for row, i in enumerate(outs):
        a0, a1 = axes[row]
        a0.axhspan(-b, b, color="tab:blue", alpha=0.15, label=f"±{b:.3f}")
        a0.stem(la[1:], auto[1:, i], basefmt=" ")
        ok = "pass" if result["auto_pass"][i] else "FAIL"
        a0.set_title(f"auto-correlation e_{onames[i]} ({ok}, Ljung–Box p = "
                     f"{result['ljung_box_p'][i]:.2g})", fontsize="small")
        a0.set_ylabel("ρ")
        a1.axhspan(-b, b, color="tab:blue", alpha=0.15)
        for j in range(nu):
            a1.plot(lc, cross[:, i, j], lw=1.0, label=f"u_{inames[j]}")
        # a constant input's pairs are None: not judged
        ok = "pass" if all(v is not False for v in result["cross_pass"][i]) else "FAIL"
        a1.set_title(f"cross-correlation e_{onames[i]} with inputs ({ok})", fontsize="small")
        if nu <= 6:
            a1.legend(fontsize="x-small", loc="upper right")
        for ax in (a0, a1):
            ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("lag (samples)")
    axes[-1, 1].set_xlabel("lag (samples)")
    return _finish(fig, path)


def plot_bode(models, spectral=None, *, omega=None, channels=None,
              path: str | os.PathLike | None = None) -> Figure:
    """Bode magnitude and phase of each model, against the spectral estimate when given.

    **Arguments:** `models` a model, list or dict name → model; `spectral` the
    `(omega, G)` pair of `validate.spectral_estimate`; `omega` rad/s (default: the spectral
    estimate's, else 200 log-spaced up to Nyquist); `channels` (i, j) pairs to draw.
    """
    from .validate import bode

    models = _models_dict(models)
    first = next(iter(models.values()))
    if omega is None:
        lo = np.min(spectral[0]) if spectral is not None else 1e-3 * np.pi / first.ts
        omega = np.logspace(np.log10(lo), np.log10(np.pi / first.ts), 200)
    chans = _channels(first.n_outputs, first.n_inputs, channels)
    fig = Figure(figsize=(3.2 * len(chans) + 0.8, 5.2), layout="constrained")
    axes = _grid(fig, 2, len(chans), sharex="col")
    f_hz = np.asarray(omega) / (2 * np.pi)
    for name, m in models.items():
        b = bode(m, omega)
        for c, (i, j) in enumerate(chans):
            axes[0, c].loglog(f_hz, b["magnitude"][:, i, j], lw=1.2, label=name)
            axes[1, c].semilogx(f_hz, b["phase_deg"][:, i, j], lw=1.2)
    if spectral is not None:
        om_s, G = spectral
        fs = np.asarray(om_s) / (2 * np.pi)
        G = np.asarray(G)
        for c, (i, j) in enumerate(chans):
            axes[0, c].loglog(fs, np.abs(G[:, i, j]), "k.", ms=3, label="spectral estimate")
            axes[1, c].semilogx(fs, np.degrees(np.unwrap(np.angle(G[:, i, j]))), "k.", ms=3)
    for c, (i, j) in enumerate(chans):
        axes[0, c].set_title(f"u{j + 1} → y{i + 1}", fontsize="small")
        axes[1, c].set_xlabel("frequency (Hz)")
        for r in range(2):
            axes[r, c].grid(alpha=0.3, which="both")
    axes[0, 0].set_ylabel("magnitude")
    axes[1, 0].set_ylabel("phase (deg)")
    axes[0, 0].legend(fontsize="x-small")
    return _finish(fig, path)


def plot_step(models, n: int, *, channels=None, path: str | os.PathLike | None = None) -> Figure:
    """Step responses (deviation from the operating point) of each model over `n` samples."""
    models = _models_dict(models)
    first = next(iter(models.values()))
    ny, nu = first.n_outputs, first.n_inputs
    if channels is None and max(ny, nu) > MAX_PANELS:
        rows = cols = list(range(MAX_PANELS))
    elif channels is None:
        rows, cols = list(range(ny)), list(range(nu))
    else:
        rows = sorted({i for i, _ in channels})
        cols = sorted({j for _, j in channels})
    fig = Figure(figsize=(2.6 * len(cols) + 0.8, 2.0 * len(rows) + 0.6), layout="constrained")
    axes = _grid(fig, len(rows), len(cols), sharex=True)
    for name, m in models.items():
        s = np.asarray(m.step_response(int(n)))
        t = m.ts * np.arange(int(n))
        for r, i in enumerate(rows):
            for c, j in enumerate(cols):
                axes[r, c].plot(t, s[:, i, j], lw=1.2, label=name)
    for r, i in enumerate(rows):
        axes[r, 0].set_ylabel(f"y{i + 1} (°C)")
        for c, j in enumerate(cols):
            axes[r, c].grid(alpha=0.3)
            if r == 0:
                axes[r, c].set_title(f"step on u{j + 1}", fontsize="small")
    for c in range(len(cols)):
        axes[-1, c].set_xlabel("time (s)")
    axes[0, 0].legend(fontsize="x-small")
    return _finish(fig, path)


def plot_pzmap(models, *, path: str | os.PathLike | None = None) -> Figure:
    """Pole-zero map in the z-plane with the unit circle (× poles, ○ transmission zeros)."""
    from .validate import poles_zeros

    models = _models_dict(models)
    fig = Figure(figsize=(5.5, 5.2), layout="constrained")
    ax = fig.add_subplot()
    th = np.linspace(0, 2 * np.pi, 400)
    ax.plot(np.cos(th), np.sin(th), color="0.6", lw=0.8)
    for k, (name, m) in enumerate(models.items()):
        pz = poles_zeros(m)
        col = f"C{k % 10}"
        p = pz["poles"]
        ax.plot(p.real, p.imag, "x", color=col, ms=8, label=f"{name} poles")
        z = pz["zeros"]
        if z is None:   # non-square: the SISO channel zeros
            z = np.concatenate([c for row in pz["channel_zeros"] for c in row if c is not None]
                               or [np.zeros(0, complex)])
        z = z[np.abs(z) < 1e6]
        if z.size:
            ax.plot(z.real, z.imag, "o", mfc="none", color=col, ms=7, label=f"{name} zeros")
    ax.set_aspect("equal")
    ax.axhline(0, color="0.8", lw=0.5)
    ax.axvline(0, color="0.8", lw=0.5)
    ax.set_xlabel("Re z")
    ax.set_ylabel("Im z")
    ax.set_title("Pole-zero map")
    ax.legend(fontsize="x-small", loc="lower left")
    ax.grid(alpha=0.3)
    return _finish(fig, path)


# ---------------------------------------------------------------- control


def plot_closed_loop(t, y, u, r, window: float = 1.0, *, names=None,
                     path: str | os.PathLike | None = None) -> Figure:
    """Closed-loop scenario: temperatures with each zone's own set point (dashed, in the zone's
    colour) and its ±`window` °C band, and inputs."""
    t = np.asarray(t, dtype=np.float64)
    y = _as_2d(y, "y")
    u = _as_2d(u, "u")
    if not (len(t) == len(y) == len(u)):
        raise DataError(f"plot_closed_loop: lengths differ: t {len(t)}, y {len(y)}, u {len(u)}")
    r = np.asarray(r, dtype=np.float64)
    if r.ndim == 1 and r.shape[0] == len(t):
        r = r[:, None]                   # one set point trajectory for every zone
    try:
        r = np.broadcast_to(r, y.shape)  # scalar, (ny,) or (T, ny)
    except ValueError:
        raise DataError(f"plot_closed_loop: set point of shape {r.shape} does not match y {y.shape}") from None
    fig = Figure(figsize=(9, 6), layout="constrained")
    a0, a1 = _grid(fig, 2, 1, sharex=True, height_ratios=[2, 1])[:, 0]
    names = names or [str(i + 1) for i in range(y.shape[1])]
    for i in range(y.shape[1]):
        line, = a0.plot(t, y[:, i], lw=1.0, label=f"y_{names[i]}" if y.shape[1] <= 8 else None)
        # each zone's own set point, in its colour, with its ±window band
        a0.plot(t, r[:, i], "--", color=line.get_color(), lw=1.0,
                label=("set point" if y.shape[1] == 1 else f"r_{names[i]}")
                if y.shape[1] <= 8 else None)
        a0.fill_between(t, r[:, i] - window, r[:, i] + window, color=line.get_color(),
                        alpha=0.12, label=f"±{window:g} °C" if i == 0 else None)
    a0.set_ylabel("temperature (°C)")
    a0.legend(fontsize="x-small", ncol=2, loc="lower right")
    for j in range(u.shape[1]):
        a1.step(t, u[:, j], where="post", lw=0.9)
    a1.set_ylim(-0.05, 1.05)
    a1.set_ylabel("heater power")
    a1.set_xlabel("time (s)")
    for ax in (a0, a1):
        ax.grid(alpha=0.3)
    return _finish(fig, path)


def plot_tuning_curve(costs, *, path: str | os.PathLike | None = None) -> Figure:
    """Cost against tuning iteration (log scale when all costs are positive).

    `costs` is a sequence, or a dict name → sequence for several runs.
    """
    runs = costs if isinstance(costs, dict) else {"cost": costs}
    fig = Figure(figsize=(6.5, 4), layout="constrained")
    ax = fig.add_subplot()
    positive = True
    for name, c in runs.items():
        c = np.asarray(c, dtype=np.float64).ravel()
        if c.size == 0:
            raise DataError(f"plot_tuning_curve: `{name}` is empty")
        positive &= bool(np.all(c > 0))
        ax.plot(np.arange(c.size), c, lw=1.2, marker="." if c.size < 60 else None, label=name)
    if positive:
        ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel("mean closed-loop cost")
    ax.grid(alpha=0.3, which="both")
    if len(runs) > 1:
        ax.legend(fontsize="small")
    return _finish(fig, path)


def plot_bed_heatmap(temps, rows: int, cols: int, *, title: str = "Zone temperatures",
                     path: str | os.PathLike | None = None) -> Figure:
    """Zone temperatures on the `rows × cols` grid of the bed (row-major, like the workloads)."""
    temps = np.asarray(temps, dtype=np.float64).ravel()
    if rows < 1 or cols < 1 or temps.size > rows * cols:
        raise DataError(f"plot_bed_heatmap: {temps.size} zones do not fit a {rows}×{cols} grid")
    grid = np.full(rows * cols, np.nan)
    grid[: temps.size] = temps
    grid = grid.reshape(rows, cols)
    fig = Figure(figsize=(1.2 * cols + 2.0, 1.1 * rows + 1.0), layout="constrained")
    ax = fig.add_subplot()
    im = ax.imshow(grid, cmap="inferno", origin="upper")
    for k, v in enumerate(temps):
        i, j = divmod(k, cols)
        ax.text(j, i, f"{v:.1f}", ha="center", va="center", fontsize="small",
                color="w" if v < np.nanmean(temps) else "k")
    ax.set_xticks(range(cols))
    ax.set_yticks(range(rows))
    fig.colorbar(im, ax=ax, label="°C")
    ax.set_title(title)
    return _finish(fig, path)


def plot_residuals(t, before, after, *, labels=("before", "after"), outputs=None,
                   path: str | os.PathLike | None = None) -> Figure:
    """Residuals of two models over time (e.g. before and after a diagnosis refit), per output."""
    t = np.asarray(t, dtype=np.float64)
    b = _as_2d(before, "before")
    a = _as_2d(after, "after")
    if b.shape != a.shape or len(t) != len(b):
        raise DataError(f"plot_residuals: shapes differ: t {t.shape}, before {b.shape}, after {a.shape}")
    outs = list(range(min(b.shape[1], MAX_PANELS))) if outputs is None else list(outputs)
    fig = Figure(figsize=(9, 1.9 * len(outs) + 0.6), layout="constrained")
    axes = _grid(fig, len(outs), 1, sharex=True)[:, 0]
    for ax, i in zip(axes, outs):
        rb = np.sqrt(np.mean(b[:, i] ** 2))
        ra = np.sqrt(np.mean(a[:, i] ** 2))
        ax.plot(t, b[:, i], lw=0.8, color="tab:red", label=f"{labels[0]} (rms {rb:.3g})")
        ax.plot(t, a[:, i], lw=0.8, color="tab:blue", label=f"{labels[1]} (rms {ra:.3g})")
        ax.set_ylabel(f"e{i + 1}")
        ax.legend(fontsize="x-small", loc="upper right")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s)")
    return _finish(fig, path)
