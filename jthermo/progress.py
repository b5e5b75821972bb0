"""Progress bars for long runs: a tqdm bar with ETA on a terminal, silent otherwise.

A bar is shown only when stderr is a TTY, the environment variable `CI` is unset and the
caller (or the CLI's `--quiet`, through `set_quiet`) did not ask for silence. Library loops
accept a `progress=` callable with signature `(i, total, info: dict) -> None`, where `i` is the
number of completed iterations; a `Progress` instance is such a callable.

```python
for guess in progress(guesses, "multi-start"):
    ...
with Progress(200, "tuning") as bar:
    for k in range(200):
        bar.update(1, cost=float(cost))
```

**Heartbeat.** Every `Progress` update, every `stage` entered and every `beat()` marks the
process as making progress (`last_beat`), and `stage(name)` names what the calling thread is
doing (`stages`): the CLI's watchdog (`jthermo.cli.watchdog`) ends a command that has made no
progress for its limit with the stage each thread was in. A long loop without a bar calls
`beat()`; JAX's compile events beat too, once the watchdog listens to them.

```python
with stage("tune: held-out evaluation"):
    for c in controllers:
        simulate(c)
        beat()
```
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

ProgressCallback = Callable[[int, int, dict], None]

_QUIET = False


#: monotonic time of the last sign of progress, and the stage of each thread that named one
_beat = {"t": time.monotonic()}
_stages: dict[int, tuple[str, str]] = {}


def beat() -> None:
    """Mark the process as making progress now (thread-safe, costs a clock read)."""
    _beat["t"] = time.monotonic()


def last_beat() -> float:
    """`time.monotonic()` at the last `beat` (or stage change, or bar update)."""
    return _beat["t"]


@contextlib.contextmanager
def stage(name: str):
    """Name what the calling thread does inside the block (its previous stage comes back
    after it); entering and leaving beat."""
    tid = threading.get_ident()
    before = _stages.get(tid)
    _stages[tid] = (threading.current_thread().name, str(name))
    beat()
    try:
        yield
    finally:
        if before is None:
            _stages.pop(tid, None)
        else:
            _stages[tid] = before
        beat()


def stages() -> list[tuple[str, str]]:
    """`(thread name, stage)` of every thread inside a `stage` block now."""
    return list(_stages.values())


def set_quiet(quiet: bool = True) -> None:
    """Silence (or re-enable) every progress bar of this process (the CLI's `--quiet`)."""
    global _QUIET
    _QUIET = bool(quiet)


def enabled(quiet: bool | None = None) -> bool:
    """Whether a bar would be drawn: not quiet, not in CI, and stderr is a terminal."""
    if quiet or (quiet is None and _QUIET):
        return False
    if os.environ.get("CI") or os.environ.get("JTHERMO_QUIET"):
        return False
    try:
        return bool(sys.stderr.isatty())
    except (AttributeError, ValueError):  # closed or replaced stream
        return False


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    try:  # numpy / jax scalars
        return f"{float(v):.4g}"
    except (TypeError, ValueError):
        return str(v)


def progress(iterable: Iterable | int, desc: str = "", quiet: bool | None = None, **kwargs):
    """Wrap `iterable` (or `range(total)` when given an int) in a tqdm bar with ETA.

    The bar is disabled (the iterable passes through untouched) when `enabled(quiet)` is false.
    Extra keyword arguments go to `tqdm.tqdm`.
    """
    from tqdm.auto import tqdm

    if isinstance(iterable, int):
        iterable = range(iterable)
    if "total" not in kwargs and hasattr(iterable, "__len__"):
        kwargs["total"] = len(iterable)
    return tqdm(_beating(iterable), desc=desc, disable=not enabled(quiet), leave=False,
                dynamic_ncols=True, file=sys.stderr, **kwargs)


def _beating(iterable: Iterable):
    """`iterable`'s items, a `beat` before each."""
    for item in iterable:
        beat()
        yield item


class Progress:
    """A bar driven by hand: `update(n, **postfix)`; also a `progress=` callback.

    **Arguments:**
    - `total`: number of iterations (None when unknown).
    - `desc`: a short label.
    - `quiet`: force silence (None: decide from the terminal, `CI` and `set_quiet`).
    """

    def __init__(self, total: int | None, desc: str = "", quiet: bool | None = None):
        self.total = total
        self.desc = desc
        self.n = 0
        self.info: dict = {}
        self._bar = None
        if enabled(quiet):
            from tqdm.auto import tqdm

            self._bar = tqdm(total=total, desc=desc, leave=False, dynamic_ncols=True,
                             file=sys.stderr)

    @property
    def active(self) -> bool:
        return self._bar is not None

    def update(self, n: int = 1, **postfix: Any) -> None:
        """Advance by `n` iterations and show `postfix` values (e.g. `cost=0.12`)."""
        beat()
        self.n += n
        if postfix:
            self.info.update(postfix)
        if self._bar is not None:
            if postfix:
                self._bar.set_postfix({k: _fmt(v) for k, v in postfix.items()}, refresh=False)
            self._bar.update(n)

    def __call__(self, i: int | str, total: int | None = None, info: dict | None = None) -> None:
        """The callback form: `i` iterations of `total` are done, with `info` to display.

        A one-line status string in place of `i` is shown as the bar's description, and the
        `(i, value)` form (iteration `i`, 0-based, ended with a cost `value`) is accepted too."""
        beat()
        if isinstance(i, str):
            self.info["status"] = i
            if self._bar is not None:
                self._bar.set_description_str(f"{self.desc}: {i}" if self.desc else i)
            return
        if total is not None and (isinstance(total, bool) or not isinstance(total, int)):
            # the `(i, value)` form (e.g. tuning's `progress(i, cost)`): iteration i, 0-based
            info = {"cost": total, **(info or {})}
            total = None
            i = int(i) + 1
        if total is not None and total != self.total:
            self.total = total
            if self._bar is not None:
                self._bar.total = total
        self.update(max(int(i) - self.n, 0), **(info or {}))

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def callback(desc: str, quiet: bool | None = None) -> Progress:
    """A fresh `Progress` whose total is set by the first call (for `progress=` arguments)."""
    return Progress(None, desc, quiet)
