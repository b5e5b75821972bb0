"""The stages of `jthermo demo` (`demo.run_demo`): its settings, the guarded stage runner and
the background threads that run the independent stages beside the others."""

from __future__ import annotations

import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .errors import ConfigError, JThermoError

SETTINGS = {
    "full": {"zones": 4, "est_s": 3600.0, "val_s": 1800.0, "tune_rollouts": 8, "tune_steps": 40,
             "tune_lr": 0.1, "eval_rollouts": 4, "scenario_s": 600.0, "diag_est_s": 3600.0,
             "diag_val_s": 1800.0, "n_starts": 4},
    "quick": {"zones": 4, "est_s": 1200.0, "val_s": 600.0, "tune_rollouts": 4, "tune_steps": 10,
              "tune_lr": 0.1, "eval_rollouts": 2, "scenario_s": 300.0, "diag_est_s": 1800.0,
              "diag_val_s": 900.0, "n_starts": 2},
}


def demo_settings(quick: bool, zones: int | None = None) -> dict:
    """`SETTINGS` of the full or `quick` demo, on a printer of `zones` zones (None: its 4).
    Every stage reads the zone count from here: the same experiment lengths, rollouts and
    steps at any N (the fits and the tuning grow with N)."""
    cfg = dict(SETTINGS["quick" if quick else "full"])
    if zones is not None:
        if isinstance(zones, bool) or not isinstance(zones, int) or zones < 1:
            raise ConfigError(f"demo: zones must be a positive integer, got {zones!r}")
        cfg["zones"] = zones
    return cfg


class StageRunner:
    """Runs guarded stages and remembers their outcome."""

    def __init__(self, total: int, quiet: bool):
        self.records: list[dict] = []
        self.total = total
        self.quiet = quiet

    def say(self, text: str) -> None:
        if not self.quiet:
            print(text, file=sys.stderr, flush=True)

    def run(self, name: str, fn: Callable[[], Any]) -> Any:
        k = len(self.records) + 1
        self.say(f"[{k}/{self.total}] {name} ...")
        t0 = time.perf_counter()
        rec: dict[str, Any] = {"stage": name}
        out = None
        try:
            out = fn()
            rec["status"] = "ok"
        except ModuleNotFoundError as exc:
            rec.update(status="missing", message=f"library piece not available: {exc.name}")
        except JThermoError as exc:
            rec.update(status="failed", message=" ".join(str(exc).split()))
        except Exception as exc:  # noqa: BLE001 - a broken stage must not stop the demo
            where = traceback.extract_tb(exc.__traceback__)[-1]
            rec.update(status="failed", message=f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]} "
                                                 f"({Path(where.filename).name}:{where.lineno})")
        rec["seconds"] = round(time.perf_counter() - t0, 2)
        self.records.append(rec)
        self.say(f"[{k}/{self.total}] {name}: {rec['status']} ({rec['seconds']:.1f} s)"
                 + (f" — {rec['message']}" if "message" in rec else ""))
        return out


def in_background(fn: Callable[[], Any]) -> Callable[[], Any]:
    """Start `fn()` in a daemon thread (an interrupted demo does not wait for it); returns the
    function that waits for it and returns its result or raises its exception. Batched
    LAPACK calls are lowered one matrix at a time first (`runtime.one_matrix_at_a_time`): two
    threads' programs must never both wait on XLA's CPU pool."""
    from .runtime import one_matrix_at_a_time

    one_matrix_at_a_time()
    box: dict[str, Any] = {}

    def target():
        try:
            box["out"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the waiting stage's guard
            box["exc"] = exc

    thread = threading.Thread(target=target, name=f"demo-{fn.__name__}", daemon=True)
    thread.start()

    def result():
        thread.join()
        if "exc" in box:
            raise box["exc"]
        return box.get("out")

    return result
