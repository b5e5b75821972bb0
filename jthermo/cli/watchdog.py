"""The command's watchdog: a command that makes no progress for `limit` seconds says so on
stderr, with the stage each thread is in, and exits with status 2, never a silent wait.

Progress is a heartbeat of `jthermo.progress` (a bar's update, a `stage` entered or left, a
`beat()` in a long loop), a JAX compile event (the end of a trace, a lowering or a backend
compile), or CPU work: the process and its child processes (a sweep's workers) using at least
`BUSY_SHARE` of one core over a check period. A stopped command has every thread asleep (the
deadlock of two LAPACK kernels waiting on XLA's pool, a lock never released, a child that never
answers): no beat and no CPU, which is what ends it; a long compile or a long trial in a
worker process works the CPU and is never ended for want of beats. The limit is `--timeout S`
(`0`: none), else `DEFAULT_LIMIT_S`. A daemon thread checks a few times per limit; a command
that ends first never hears of it. With `JTHERMO_DEBUG` set the Python stack of every thread
follows the message (`faulthandler`).

The exit is `os._exit`: a deadlocked thread cannot be joined, and an interpreter teardown would
wait on it. Every file the commands write is written by a rename (`io.write_json`, `stored`),
so none is left half-written.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable

from .. import progress

#: seconds without progress after which a command ends (`--timeout` overrides; 0: never)
DEFAULT_LIMIT_S = 1200.0
#: exit status of a command the watchdog ends (the CLI's error status)
EXIT_STALLED = 2
#: share of one core the process family must use over a check period to count as working
BUSY_SHARE = 0.01

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
    the CPU seconds its processes used while it made no progress."""
    where = "; ".join(f"{name}: {st}" for name, st in progress.stages()) or "no stage named"
    return (f"jthermo: error: {command}: no progress for {limit:g} s, stopped in stage "
            f"[{where}]; {cpu_s:.1f} CPU s used meanwhile (every thread asleep: a deadlock?); "
            "--timeout S changes the limit (0: none)")


def _stat(pid) -> list[bytes] | None:
    """The fields of /proc/PID/stat after the command name (state first), None if unreadable."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()
    except (OSError, IndexError):
        return None


_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def family_cpu_seconds(pid: int | None = None) -> float:
    """CPU seconds (user + system) of process `pid` (default this one) and of its running
    child processes (Linux's /proc; elsewhere this process's alone)."""
    own = str(os.getpid() if pid is None else pid)
    if pid is None:
        total = time.process_time()
    else:
        f = _stat(pid)
        total = 0.0 if f is None else (int(f[11]) + int(f[12])) / _TICK
    try:
        pids = [p for p in os.listdir("/proc") if p.isdigit()]
    except OSError:
        return total
    for p in pids:
        f = _stat(p)
        if f is not None and f[1].decode() == own:      # ppid; utime, stime: 14th, 15th
            total += (int(f[11]) + int(f[12])) / _TICK
    return total


class Stalled(RuntimeError):
    """`run_watched`'s child made no progress (no CPU work) for its limit."""


def run_watched(argv: list[str], idle_s: float, **popen) -> subprocess.CompletedProcess:
    """`subprocess.run(argv, capture_output=True, text=True, **popen)`, except that a child
    whose processes use less than `BUSY_SHARE` of a core for `idle_s` seconds on end (every
    thread asleep: a deadlock) is killed and `Stalled` raised; a slow child on a loaded
    machine is waited for. For tests and studies that must fail rather than hang."""
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            **popen)
    box: dict = {}
    reader = threading.Thread(target=lambda: box.update(zip(("out", "err"),
                                                              proc.communicate())), daemon=True)
    reader.start()
    period = min(max(idle_s / 8.0, 0.05), 5.0)
    cpu, busy_at = family_cpu_seconds(proc.pid), time.monotonic()
    while True:
        reader.join(period)
        if not reader.is_alive():
            return subprocess.CompletedProcess(argv, proc.returncode, box.get("out", ""),
                                               box.get("err", ""))
        now, before, cpu = time.monotonic(), cpu, family_cpu_seconds(proc.pid)
        if cpu - before >= BUSY_SHARE * period:
            busy_at = now
        if now - busy_at >= idle_s:
            proc.kill()
            reader.join()
            raise Stalled(f"{' '.join(map(str, argv[:3]))}...: no CPU work for {idle_s:g} s "
                          f"(every thread asleep); stderr tail: {box.get('err', '')[-500:]}")


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

    @staticmethod
    def _others_cpu() -> float:
        """`family_cpu_seconds` less this (the watchdog's) thread's own: its /proc scans."""
        return family_cpu_seconds() - time.thread_time()

    def _watch(self) -> None:
        period = min(max(self.limit / 8.0, 0.05), 5.0)
        cpu = self._others_cpu()
        busy_at, since_cpu = time.monotonic(), cpu
        while not self._stop.wait(period):
            now, before, cpu = time.monotonic(), cpu, self._others_cpu()
            if cpu - before >= BUSY_SHARE * period:
                busy_at = now
            last = max(progress.last_beat(), busy_at)
            if last > now - period:
                since_cpu = cpu
            if now - last >= self.limit:
                self.on_stall(message(self.command, self.limit, cpu - since_cpu))
                return


def _exit_stalled(text: str) -> None:
    print(text, file=sys.stderr, flush=True)
    if os.environ.get("JTHERMO_DEBUG"):
        import faulthandler

        faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
    os._exit(EXIT_STALLED)
