"""Shared pieces of the `jthermo` command, JAX-free: the limits and argument types of the
options, the parser that makes usage errors one line, and the checks every command makes on
its input and output paths before it calls the library."""

from __future__ import annotations

import argparse
import importlib
import math
import os
import sys
from pathlib import Path

from ..errors import ConfigError, DataError

MAX_ZONES = 256
MAX_DURATION = 7 * 24 * 3600.0
MAX_ROLLOUTS = 65536
MAX_ORDER = 64


class UsageError(Exception):
    """A command-line usage error (argparse's, made one line)."""


class Parser(argparse.ArgumentParser):
    def error(self, message: str):  # one line, no usage dump
        raise UsageError(f"{self.prog}: {message}")


# ---------------------------------------------------------------- argument types


def number(text: str, cast, what: str):
    """`cast(text)`, or argparse's one-line error naming what was expected."""
    try:
        return cast(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None


def positive_int(limit: int):
    def conv(text: str) -> int:
        v = number(text, int, "a positive integer")
        if not 1 <= v <= limit:
            raise argparse.ArgumentTypeError(f"must lie in 1..{limit}, got {v}")
        return v

    conv.__name__ = "positive integer"
    return conv


def seed(text: str) -> int:
    v = number(text, int, "an integer seed")
    if not 0 <= v < 2**32:
        raise argparse.ArgumentTypeError(f"seed must lie in 0..2**32-1, got {v}")
    return v


def duration(text: str) -> float:
    v = number(text, float, "seconds")
    if not (math.isfinite(v) and 0 < v <= MAX_DURATION):
        raise argparse.ArgumentTypeError(f"duration must lie in (0, {MAX_DURATION:g}] s, got {text}")
    return v


def timeout(text: str) -> float:
    v = number(text, float, "seconds")
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"timeout must be a number of seconds >= 0, got {text}")
    return v


TIMEOUT_HELP = ("end the command (exit status 2, naming its stage) once it has made no "
                "progress for S seconds (default 1200; 0: never)")


def add_timeout(sp: argparse.ArgumentParser, default=argparse.SUPPRESS) -> None:
    """`--timeout S` (`watchdog`): on the command line before the command or after it (a
    command's parser leaves the value alone unless given there)."""
    sp.add_argument("--timeout", type=timeout, default=default, metavar="S", help=TIMEOUT_HELP)


def add_common(sp: argparse.ArgumentParser, plot: bool = True) -> None:
    """The options every command takes: `--json`, `--seed`, `--quiet`, `--verbose`,
    `--no-cache`, `--timeout` (and `--plot`)."""
    add_timeout(sp)
    sp.add_argument("--json", metavar="PATH", help="write a JSON report here (atomically)")
    sp.add_argument("--seed", type=seed, default=0, help="random seed (default 0)")
    sp.add_argument("--quiet", action="store_true", help="no progress bars")
    sp.add_argument("--verbose", action="store_true",
                    help="say which compilation cache is used (one line on stderr)")
    sp.add_argument("--no-cache", action="store_true",
                    help="compile afresh, without the persistent compilation cache "
                         "(also: JTHERMO_NO_CACHE=1)")
    if plot:
        sp.add_argument("--plot", metavar="DIR", help="write figures (PNG) into DIR")


# ---------------------------------------------------------------- input and output checks


def input_file(path: str, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise ConfigError(f"{what} {p}: no such file")
    if p.is_dir():
        raise ConfigError(f"{what} {p}: is a directory")
    return p


def output_path(path: str | None, what: str) -> Path | None:
    if path is None:
        return None
    p = Path(path)
    if p.is_dir():
        raise ConfigError(f"{what} {p}: is a directory")
    parent = p.parent if str(p.parent) else Path(".")
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK):
        raise ConfigError(f"{what} {p}: cannot write into {probe}")
    return p


def distinct_outputs(*paths: Path | None) -> None:
    seen: dict = {}
    for p in paths:
        if p is None:
            continue
        key = p.resolve()
        if key in seen:
            raise ConfigError(f"two outputs write the same file {p}")
        seen[key] = p


def load_data(path: str, what: str = "data"):
    from .. import data as data_mod

    input_file(path, what)
    return data_mod.load(path)


def same_layout(est, val, what: str = "validation") -> None:
    if (est.n_inputs, est.n_outputs, est.w.shape[1]) != (val.n_inputs, val.n_outputs, val.w.shape[1]):
        raise DataError(
            f"{what} data has {val.n_inputs} inputs, {val.n_outputs} outputs, {val.w.shape[1]} signals; "
            f"the estimation data has {est.n_inputs}, {est.n_outputs}, {est.w.shape[1]}")


def require(module: str, what: str):
    """`importlib.import_module(module)`, or a one-line error when this build lacks it."""
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name and (exc.name == module or module.startswith(exc.name + ".")):
            raise ConfigError(f"{what} is not available in this jthermo build (no module {module})") from None
        raise


def plot_dir(args) -> Path | None:
    d = getattr(args, "plot", None)
    if d is None:
        return None
    p = Path(d)
    if p.exists() and not p.is_dir():
        raise ConfigError(f"--plot {p}: exists and is not a directory")
    require("jthermo.plots", "--plot (figures)")
    return p


# ---------------------------------------------------------------- progress and messages


def progress_bar(args, desc: str, total: int | None = None):
    from ..progress import Progress

    return Progress(total, desc, quiet=True if args.quiet else None)


def write_report(args, path: Path | None, report: dict) -> dict:
    """`report` with the command's wall time so far (`seconds`, split into `compile_s` and
    `run_s`), written to `path` as JSON when a path is given; returns the report written."""
    from ..io import write_json

    clock = getattr(args, "stopwatch", None)
    if clock is not None:
        report = {**report, **clock.split()}
    write_json(path, report)
    return report


def exit_now(code: int):
    """End the command's process with status `code` at once: flush stdout and stderr, run the
    `atexit` handlers (JAX's, filelock's, logging's), then `os._exit`, skipping the
    interpreter's teardown of its ~1000 modules and JAX's objects (most of a warm `jthermo
    simulate`'s exit: measured by `python benchmarks/simulate_teardown.py`). Only for
    the process the command owns (`python -m jthermo.cli`, `cli.entry`), never for an
    in-process `main()`."""
    import atexit

    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed pipe (`jthermo ... | head`)
            pass
    atexit._run_exitfuncs()
    os._exit(code)


def info(args, text: str) -> None:
    if not args.quiet:
        print(text, file=sys.stdout)


def summary_line(report: dict, keys) -> str:
    parts = []
    for k in keys:
        v = report.get(k)
        if isinstance(v, float):
            parts.append(f"{k}={v:.4g}")
        elif v is not None:
            parts.append(f"{k}={v}")
    return "  ".join(parts)
