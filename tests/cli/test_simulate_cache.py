"""`jthermo simulate` with its traced programs kept in the cache directory
(`stored.exported_call`): the first process writes them, a second reads them and reports the
same figures, and corrupt files give the same figures again (and are rewritten). A cache
switched off writes none: tests/test_stored_export.py."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from jthermo import runtime, stored

ARGV = ["simulate", "--scenario", "tracking", "--controller", "pi", "--zones", "2",
        "--rollouts", "2", "--duration", "120", "--quiet"]


def _simulate(tmp_path: Path, cache: Path) -> dict:
    js = tmp_path / "sim.json"
    js.unlink(missing_ok=True)
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("JAX_") and k not in (runtime.ENV_DIR, runtime.ENV_OFF)}
    env.update({runtime.ENV_DIR: str(cache), "JAX_PLATFORMS": "cpu"})
    r = subprocess.run([sys.executable, "-m", "jthermo.cli", *ARGV, "--json", str(js)],
                       check=False, capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return json.loads(js.read_text())


def _exports(cache: Path, pattern: str = "*.jaxexport") -> dict[str, bytes]:
    d = cache / stored.EXPORT_SUBDIR
    return {p.name: p.read_bytes() for p in d.glob(pattern)} if d.is_dir() else {}


def test_simulate_exports_once_and_reads_back_the_same_figures(tmp_path):
    cache = tmp_path / "cache"
    first = _simulate(tmp_path, cache)
    files = _exports(cache)
    # the printer's design model and the run program
    assert len(files) == 2, sorted(files)
    # and the design model's numbers (stored.cached_arrays)
    numbers = _exports(cache, "*.npz")
    assert len(numbers) == 1, sorted(numbers)
    compiled = set(cache.glob("*-cache"))
    second = _simulate(tmp_path, cache)
    assert second["metrics"] == first["metrics"]
    assert _exports(cache) == files, "a warm run rewrote its exported programs"
    assert _exports(cache, "*.npz") == numbers, "a warm run rewrote the design model"
    assert set(cache.glob("*-cache")) == compiled, "a warm run compiled what the first had"
    for name in [*files, *numbers]:
        (cache / stored.EXPORT_SUBDIR / name).write_bytes(b"corrupt" * 100)
    third = _simulate(tmp_path, cache)
    assert third["metrics"] == first["metrics"]
    assert _exports(cache) == files, "corrupt files were not replaced by the same programs"
    assert _exports(cache, "*.npz") == numbers, "a corrupt design model was not rewritten"


def test_the_command_process_flushes_its_output_and_keeps_its_exit_status():
    """`python -m jthermo.cli` ends with `common.exit_now` (no interpreter teardown): what it
    printed still arrives through a pipe, and the status is main's."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    ok = subprocess.run([sys.executable, "-m", "jthermo.cli", "--version"], check=False,
                        capture_output=True, text=True, timeout=120, env=env)
    assert ok.returncode == 0 and ok.stdout.startswith("jthermo "), ok
    bad = subprocess.run([sys.executable, "-m", "jthermo.cli", "simulate", "--scenario",
                          "tracking", "--zones", "x"], check=False, capture_output=True, text=True,
                         timeout=120, env=env)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == [
        "jthermo: error: jthermo simulate: argument --zones: expected a positive integer, got 'x'"]
