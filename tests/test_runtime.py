"""The persistent compilation cache and the compile/run split of `--json` reports
(`jthermo.runtime`): a second process compiles nothing new, `--no-cache` writes nothing, and
a cache directory that cannot be written leaves the command working."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from jthermo import runtime


def _jthermo(tmp_path: Path, cache: Path, *extra: str, env: dict | None = None):
    """`jthermo generate` (a cheap command that compiles) in a fresh process; returns the run
    and its JSON report."""
    out, js = tmp_path / "g.csv", tmp_path / "g.json"
    js.unlink(missing_ok=True)
    e = {k: v for k, v in os.environ.items()
         if not k.startswith("JAX_") and k not in (runtime.ENV_DIR, runtime.ENV_OFF)}
    e.update({runtime.ENV_DIR: str(cache), "JAX_PLATFORMS": "cpu", **(env or {})})
    r = subprocess.run([sys.executable, "-m", "jthermo.cli", "generate", "--zones", "2",
                        "--duration", "60", "--out", str(out), "--json", str(js), "--quiet",
                        *extra], check=False, capture_output=True, text=True, timeout=300,
                       env=e)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    return r, json.loads(js.read_text())


def _entries(d: Path) -> set[str]:
    return {p.name for p in d.glob("*-cache")} if d.is_dir() else set()


def test_second_process_compiles_nothing_new_and_no_cache_writes_nothing(tmp_path):
    cache = tmp_path / "cache"
    _, first = _jthermo(tmp_path, cache)
    record = (tmp_path / "g.csv").read_bytes()
    written = _entries(cache)
    assert written, "the first run wrote no cache entries"
    assert {"seconds", "compile_s", "run_s"} <= set(first)
    assert first["compile_s"] > 0 and first["run_s"] >= 0
    assert first["compile_s"] + first["run_s"] == pytest.approx(first["seconds"], abs=2e-3)
    r, _ = _jthermo(tmp_path, cache, "--verbose")
    assert _entries(cache) == written, "the second run compiled something the first had cached"
    assert (tmp_path / "g.csv").read_bytes() == record, "cached code gave another record"
    assert f"compilation cache {cache} ({len(written)} entries)" in r.stderr
    fresh = tmp_path / "fresh"
    _jthermo(tmp_path, fresh, "--no-cache")
    assert not _entries(fresh)


def test_unwritable_cache_dir_still_runs(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    r, rep = _jthermo(tmp_path, blocker / "cache", "--verbose")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, lines   # one info line, no warning, no traceback
    assert lines[0].startswith(f"jthermo: compilation cache off (cannot write {blocker / 'cache'}")
    assert rep["n_samples"] == 60


def test_cache_dir_resolution(monkeypatch, tmp_path):
    monkeypatch.delenv(runtime.ENV_DIR, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert runtime.default_cache_dir() == tmp_path / "xdg" / "jthermo" / "jax"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert runtime.default_cache_dir() == tmp_path / "home" / ".cache" / "jthermo" / "jax"
    monkeypatch.setenv(runtime.ENV_DIR, str(tmp_path / "mine"))
    assert runtime.default_cache_dir() == tmp_path / "mine"


def test_union_of_compile_spans_counts_nested_spans_once():
    spans = [(0.0, 4.0), (1.0, 2.0), (3.0, 6.0), (8.0, 9.0), (-5.0, -4.0)]
    assert runtime.union_seconds(spans, 0.0, 10.0) == pytest.approx(7.0)
    assert runtime.union_seconds(spans, 5.0, 8.5) == pytest.approx(1.5)
    assert runtime.union_seconds([], 0.0, 1.0) == 0.0


def test_one_shot_options_compile_and_an_unknown_option_is_dropped(monkeypatch):
    import jax
    import numpy as np

    runtime.accepted_items.cache_clear()
    opts = runtime.one_shot()   # ONE_SHOT, less what this XLA lacks (-O0 stays)
    assert opts.items() <= runtime.ONE_SHOT.items() and "xla_backend_optimization_level" in opts
    out = jax.jit(lambda x: 2 * x, compiler_options=runtime.one_shot())(np.float64(3))
    assert float(out) == 6.0
    # an XLA without an option refuses to compile: `one_shot` leaves it out instead
    monkeypatch.setattr(runtime, "ONE_SHOT", dict(runtime.ONE_SHOT, xla_cpu_no_such_option=True))
    monkeypatch.setattr(runtime, "NEWER_OPTIONS",
                        runtime.NEWER_OPTIONS + ("xla_cpu_no_such_option",))
    runtime.accepted_items.cache_clear()
    try:
        assert runtime.one_shot() == {"xla_backend_optimization_level": 0}
        assert runtime.accepted({"xla_cpu_no_such_option": True}) == {}
    finally:
        runtime.accepted_items.cache_clear()


def test_top_level_is_false_inside_a_trace():
    import jax

    seen = []
    jax.jit(lambda x: seen.append(runtime.top_level()) or x)(1.0)
    jax.grad(lambda x: seen.append(runtime.top_level()) or x ** 2)(1.0)
    assert runtime.top_level() and seen == [False, False]
