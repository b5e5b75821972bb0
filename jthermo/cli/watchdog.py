"""The command's watchdog: a command that makes no progress for `limit` seconds says so on
stderr, with the stage each thread is in, and exits with status 2, never a silent wait.

Progress is any heartbeat of `jthermo.progress` (a bar's update, a `stage` entered or left, a
`beat()` in a long loop) and every JAX compile event (the end of a trace, a lowering or a
backend compile: a cold command compiles for minutes between two steps of its loops). A
daemon thread looks at the last beat a few times per limit; a command that ends first never
hears of it. The limit is `--timeout S` (`0`: none), else `DEFAULT_LIMIT_S`: far above the
longest gap between two beats of any command measured on a loaded two-core machine (one
backend compile, about a minute), so that only a command that has stopped trips it; a stopped
command typically has every thread asleep (a deadlock), which the message names by the CPU
seconds the process used meanwhile. With `JTHERMO_DEBUG` set the Python stack of every thread
follows the message (`faulthandler`).

The exit is `os._exit`: a deadlocked thread cannot be joined, and an interpreter teardown would
wait on it. Every file the commands write is written by a rename (`io.write_json`,
`stored`), so none is left half-written.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable

from .. import progress

#: seconds without progress after which a command ends (`--timeout` overrides; 0: never)
DEFAULT_LIMIT_S = 1200.0
#: exit status of a command the watchdog ends (the CLI's error status)
EXIT_STALLED = 2

_listening = {"on": False}


def _on_compile_event(*_args, **_kwargs) -> None:
    progress.beat()


def listen_to_compiles() -> None:
    """Make every JAX compile event (trace, lowering, backend compile, cache hit) a beat."""
    if _listening["on"]:
        return
    _listening["on"] = True
    import jax.monitoring

    jax.monitoring.register_event_duration_secs_listener(_on_compile_event)
    jax.monitoring.register_event_listener(_on_compile_event)


def message(command: str, limit: float, cpu_s: float) -> str:
    """The one line said on a stall: the command, the limit, the stages of its threads and
    the CPU seconds used while it made no progress."""
    where = "; ".join(f"{name}: {st}" for name, st in progress.stages()) or "no stage named"
    asleep = " (every thread asleep: a deadlock?)" if cpu_s < 0.05 * limit else ""
    return (f"jthermo: error: {command}: no progress for {limit:g} s, stopped in stage "
            f"[{where}]; {cpu_s:.1f} CPU s used meanwhile{asleep}; --timeout S changes the "
            "limit (0: none)")


class Watchdog:
    """`start()` a daemon thread that calls `on_stall(message)` once the process has made no
    progress (`progress.last_beat`) for `limit` seconds; `stop()` ends it. Default `on_stall`:
    the message on stderr, then `os._exit(EXIT_STALLED)`."""

    def __init__(self, limit: float, command: str,
                 on_stall: Callable[[str], None] | None = None):
        self.limit = float(limit)
        self.command = command
        self.on_stall = on_stall or _exit_stalled
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "Watchdog":
        if self.limit > 0 and self._thread is None:
            progress.beat()
            self._thread = threading.Thread(target=self._watch, name="jthermo-watchdog",
                                            daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()

    def __enter__(self) -> "Watchdog":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _watch(self) -> None:
        period = min(max(self.limit / 8.0, 0.05), 5.0)
        marks = [(progress.last_beat(), time.process_time())]
        while not self._stop.wait(period):
            now, cpu = time.monotonic(), time.process_time()
            last = progress.last_beat()
            if marks[-1][0] != last:
                marks = [(last, cpu)]
            if now - last >= self.limit:
                self.on_stall(message(self.command, self.limit, cpu - marks[0][1]))
                return


def _exit_stalled(text: str) -> None:
    print(text, file=sys.stderr, flush=True)
    if os.environ.get("JTHERMO_DEBUG"):
        import faulthandler

        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
    os._exit(EXIT_STALLED)
