"""Numeric results kept on disk (`stored.cached_arrays`): a miss computes and writes an
`.npz`, a hit reads it without computing and gives the same arrays bit for bit; a corrupt or
foreign file is recomputed and rewritten, the cache off or a trace reads and writes nothing;
the printer's design model of `jthermo simulate` is read back equal."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jthermo import runtime, stored


def poly(x, n: int) -> dict:
    """A deterministic function of an array and a static int."""
    return {"y": jnp.cumsum(x) ** n, "s": jnp.sum(x, dtype=jnp.float64)}


class Counting:
    def __init__(self):
        self.calls = 0

    def __call__(self, *args):
        self.calls += 1
        return poly(*args)


@pytest.fixture
def folder(monkeypatch, tmp_path):
    monkeypatch.setitem(runtime.state, "dir", tmp_path)
    return tmp_path / stored.EXPORT_SUBDIR


def _files(folder):
    return sorted(folder.glob("*.npz")) if folder.is_dir() else []


def _same(out, ref):
    assert list(out) == list(ref)
    for k in ref:
        assert isinstance(out[k], jax.Array)
        assert out[k].dtype == ref[k].dtype and out[k].shape == ref[k].shape
        np.testing.assert_array_equal(np.asarray(out[k]), np.asarray(ref[k]))


X = jnp.linspace(0.1, 1.3, 7)


def test_miss_writes_and_hit_reads_without_computing(folder):
    f = Counting()
    ref = poly(X, 3)
    _same(stored.cached_arrays(poly, (X, 3), f), ref)
    assert f.calls == 1 and len(_files(folder)) == 1
    blob = _files(folder)[0].read_bytes()
    _same(stored.cached_arrays(poly, (X, 3), f), ref)
    assert f.calls == 1, "a hit computed again"
    assert _files(folder)[0].read_bytes() == blob
    # other input bytes, another static leaf: other keys, computed
    _same(stored.cached_arrays(poly, (X + 1e-12, 3), f), poly(X + 1e-12, 3))
    _same(stored.cached_arrays(poly, (X, 2), f), poly(X, 2))
    assert f.calls == 3 and len(_files(folder)) == 3


@pytest.mark.parametrize("damage", ["truncate", "garbage", "foreign", "layout"])
def test_a_corrupt_or_foreign_file_is_recomputed_and_rewritten(folder, damage):
    f = Counting()
    stored.cached_arrays(poly, (X, 3), f)
    path = _files(folder)[0]
    good = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(good[: len(good) // 2])
    elif damage == "garbage":
        path.write_bytes(b"garbage" * 50)
    elif damage == "foreign":   # another key's file copied over this one
        stored.cached_arrays(poly, (X, 2), f)
        other = next(p for p in _files(folder) if p != path)
        path.write_bytes(other.read_bytes())
    else:                       # a layout line that does not match the arrays
        head, _, rest = good.partition(b"\n")
        path.write_bytes(head + b"\n" + rest.replace(b"y:", b"z:", 1))
    calls = f.calls
    _same(stored.cached_arrays(poly, (X, 3), f), poly(X, 3))
    assert f.calls == calls + 1
    assert path.read_bytes() == good, "the damaged file was not rewritten"


def test_cache_off_or_inside_a_trace_reads_and_writes_nothing(folder, monkeypatch):
    f = Counting()
    stored.cached_arrays(poly, (X, 3), f)
    files = {p: p.read_bytes() for p in _files(folder)}
    monkeypatch.setitem(runtime.state, "dir", None)
    _same(stored.cached_arrays(poly, (X, 3), f), poly(X, 3))
    assert f.calls == 2
    monkeypatch.setitem(runtime.state, "dir", folder.parent)
    out = jax.jit(lambda x: stored.cached_arrays(poly, (x, 3), f)["y"])(X)
    np.testing.assert_array_equal(np.asarray(out), np.asarray(poly(X, 3)["y"]))
    assert f.calls == 3
    assert {p: p.read_bytes() for p in _files(folder)} == files


def test_unwritable_folder_still_gives_the_result(folder):
    folder.parent.mkdir(parents=True, exist_ok=True)
    folder.write_text("a file where the folder should be")
    f = Counting()
    for _ in range(2):
        _same(stored.cached_arrays(poly, (X, 3), f), poly(X, 3))
    assert f.calls == 2


def test_printer_design_model_read_back_equal(folder, monkeypatch):
    """`cli.printer_model.stored_printer_model`: the second call reads the file (the program is
    not run) and gives the same model and the same lambda-PI gains bit for bit as the cache off."""
    from jthermo import closedloop
    from jthermo.cli import printer_model
    from jthermo.control.design import design
    from jthermo.printer import make_printer

    printer = make_printer(2, closedloop.REALISTIC_EFFECTS, powder="PA12", seed=0)
    calls = []
    program = printer_model.printer_model_program
    monkeypatch.setattr(printer_model, "printer_model_program",
                        lambda p: calls.append(1) or program(p))
    first = printer_model.stored_printer_model(printer)
    second = printer_model.stored_printer_model(printer)
    assert len(calls) == 1 and len(_files(folder)) == 1
    monkeypatch.setitem(runtime.state, "dir", None)
    off = printer_model.stored_printer_model(printer)
    assert len(calls) == 2
    for m in (first, second):
        assert jax.tree.structure(m) == jax.tree.structure(off)
        for a, b in zip(jax.tree.leaves(m), jax.tree.leaves(off)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    ka = design("pi_lambda", second)
    kb = design("pi_lambda", off)
    for a, b in zip(jax.tree.leaves(ka), jax.tree.leaves(kb)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
