"""The command's watchdog (`jthermo.cli.watchdog`) and the heartbeat it listens to
(`jthermo.progress`): a stage that stops making progress ends the command with status 2 and a
line naming the stage; progress (bars, stages, beats) is what resets it."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import pytest

from jthermo import progress
from jthermo.cli import main
from jthermo.cli.watchdog import (EXIT_STALLED, Stalled, Watchdog, family_cpu_seconds, message,
                                  run_watched)

#: seconds a test waits for a watchdog that should fire at once (a guard, never reached)
GUARD_S = 60


def test_a_stalled_stage_is_named_by_the_watchdog():
    said, fired, release = [], threading.Event(), threading.Event()

    def on_stall(text):
        said.append(text)
        fired.set()

    def stalled():
        with progress.stage("fake stall"):
            release.wait(GUARD_S)

    worker = threading.Thread(target=stalled, name="fake-worker")
    worker.start()
    try:
        with Watchdog(0.2, "jthermo fake", on_stall=on_stall):
            assert fired.wait(GUARD_S)
    finally:
        release.set()
        worker.join()
    assert len(said) == 1
    assert "jthermo fake: no progress for 0.2 s" in said[0]
    assert "fake-worker: fake stall" in said[0]
    assert ("fake-worker", "fake stall") not in progress.stages()    # left with its block


def test_stages_nest_and_every_heartbeat_moves_the_clock():
    t0 = progress.last_beat()
    with progress.stage("outer"):
        with progress.stage("inner"):
            assert progress.stages()[-1][1] == "inner"
        assert (threading.current_thread().name, "outer") in progress.stages()
    assert all(st not in ("outer", "inner") for _, st in progress.stages())
    t1 = progress.last_beat()
    assert t1 >= t0
    bar = progress.Progress(3, "x", quiet=True)
    bar.update(1)
    assert progress.last_beat() >= t1
    t2 = progress.last_beat()
    assert list(progress.progress([1, 2], quiet=True)) == [1, 2]
    assert progress.last_beat() >= t2


def test_the_message_is_one_line_with_the_cpu_used():
    text = message("jthermo tune", 600, 0.2)
    assert "\n" not in text and text.startswith("jthermo: error: jthermo tune")
    assert "no progress for 600 s" in text and "0.2 CPU s used meanwhile" in text


def test_cpu_work_counts_as_progress():
    """A thread that computes without beating keeps the watchdog quiet while it works; once
    it sleeps the watchdog fires."""
    fired, done = threading.Event(), threading.Event()

    def spin():
        with progress.stage("computing"):
            end = time.process_time() + 2.0      # two CPU seconds of work, no beat
            while time.process_time() < end:
                sum(range(1000))
            done.set()
            fired.wait(GUARD_S)

    worker = threading.Thread(target=spin, name="spinner")
    said = []
    with Watchdog(2.0, "jthermo fake", on_stall=lambda t: (said.append(
            (done.is_set(), t)), fired.set())):
        worker.start()
        assert fired.wait(GUARD_S)
    worker.join()
    assert said and said[0][0], said      # it fired only once the work was done
    assert "spinner: computing" in said[0][1]


def test_family_cpu_seconds_grows_with_work():
    t0 = family_cpu_seconds()
    end = time.process_time() + 0.2
    while time.process_time() < end:
        pass
    assert family_cpu_seconds() >= t0 + 0.2


def test_no_limit_starts_no_thread():
    dog = Watchdog(0, "jthermo fake").start()
    assert dog._thread is None


@pytest.mark.parametrize("value", ["-1", "nan", "soon"])
def test_a_bad_timeout_is_one_line_and_status_2(capsys, value):
    assert main(["export", "ctrl.eqx", "--to", "json", "--out", "d", "--timeout", value]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("jthermo: error:") and "\n" not in err and "timeout" in err


CHILD = r"""
import sys, time
import jax                     # imported before the command: its stage starts at once
import jthermo.cli as cli
from jthermo.progress import stage

def fake(args):
    with stage("fake stall"):
        time.sleep(120)

cli.COMMANDS["export"] = fake
sys.exit(cli.main(sys.argv[1:]))
"""


@pytest.mark.parametrize("where", ["before", "after"])
def test_a_stalled_command_exits_2_naming_its_stage(tmp_path, where):
    """`--timeout S` before or after the command's name; the child would sleep 120 s."""
    cmd = ["export", "c.eqx", "--to", "json", "--out", str(tmp_path / "d")]
    opt = ["--timeout", "5"]
    argv = opt + cmd if where == "before" else cmd + opt
    r = subprocess.run([sys.executable, "-c", CHILD, *argv], capture_output=True, text=True,
                       timeout=GUARD_S, env={**os.environ, "JTHERMO_NO_CACHE": "1"})
    assert r.returncode == EXIT_STALLED
    line = r.stderr.strip().splitlines()[-1]
    assert "jthermo export: no progress for 5 s" in line
    assert "MainThread: fake stall" in line
    assert not (tmp_path / "d").exists()


def test_run_watched_kills_a_sleeping_child_and_returns_a_working_one():
    with pytest.raises(Stalled, match="no CPU work for 1 s"):
        run_watched([sys.executable, "-c", "import time; time.sleep(120)"], 1.0)
    r = run_watched([sys.executable, "-c", "print(sum(range(10**6)))"], 30.0)
    assert r.returncode == 0 and r.stdout.strip() == str(sum(range(10**6)))
