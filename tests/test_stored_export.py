"""Traced programs kept on disk (`stored.exported_call`): a miss traces and writes a
`jax.export` file, a hit reads it without tracing and gives the same figures, and every
file that cannot serve (corrupt, copied from another key, unwritable folder), a disabled
cache and a call inside a trace fall back to the plain jitted function."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import export

from jthermo import runtime, stored


class Gain(eqx.Module):
    k: jax.Array
    label: str = eqx.field(static=True)


def scaled_sums(g: Gain, x, n: int):
    """A small program with an equinox module, a static int and a typed-free array input."""
    return {"y": g.k * jnp.cumsum(x)[:n], "n": n, "label_len": len(g.label)}


class Counting:
    """`eqx.filter_jit(scaled_sums)` that counts its calls."""

    def __init__(self):
        self.calls = 0
        self.jitted = eqx.filter_jit(scaled_sums)

    def __call__(self, *args):
        self.calls += 1
        return self.jitted(*args)


@pytest.fixture
def folder(monkeypatch, tmp_path):
    """The export folder of a cache directory in `tmp_path` (the process's compilation cache
    stays where it is: only the files of `exported_call` move)."""
    monkeypatch.setitem(runtime.state, "dir", tmp_path)
    return tmp_path / stored.EXPORT_SUBDIR


def _args(n=3, size=5, label="a"):
    g = Gain(k=jnp.asarray(2.0, jnp.float32), label=label)
    return g, jnp.arange(size, dtype=jnp.float32), n


def _same(out, ref):
    assert set(out) == set(ref)
    for k in ref:
        np.testing.assert_array_equal(np.asarray(out[k]), np.asarray(ref[k]))


def _files(folder):
    return sorted(folder.glob("*.jaxexport")) if folder.is_dir() else []


def test_miss_writes_a_file_and_a_hit_reads_it_without_tracing(folder, monkeypatch):
    args = _args()
    ref = scaled_sums(*args)
    fb = Counting()
    _same(stored.exported_call(scaled_sums, args, fb), ref)
    assert fb.calls == 0 and len(_files(folder)) == 1

    def no_tracing(*a, **k):
        raise AssertionError("traced again although the file was there")

    monkeypatch.setattr(export, "export", no_tracing)
    _same(stored.exported_call(scaled_sums, args, fb), ref)
    assert fb.calls == 0 and len(_files(folder)) == 1
    monkeypatch.undo()
    monkeypatch.setitem(runtime.state, "dir", folder.parent)
    # another static value, another shape, another static field: other programs, other files
    for other in (_args(n=2), _args(size=6), _args(label="bb")):
        _same(stored.exported_call(scaled_sums, other, fb), scaled_sums(*other))
    assert fb.calls == 0 and len(_files(folder)) == 4


@pytest.mark.parametrize("damage", ["garbage", "truncated", "other_key", "empty"])
def test_a_damaged_or_foreign_file_still_gives_the_right_result(folder, damage):
    args, other = _args(), _args(n=2)
    fb = Counting()
    stored.exported_call(scaled_sums, args, fb)
    stored.exported_call(scaled_sums, other, fb)
    files = _files(folder)
    mine = next(p for p in files if _reads_as(p, args))
    theirs = next(p for p in files if p != mine)
    blob = mine.read_bytes()
    mine.write_bytes({"garbage": b"\x00not an export" * 50, "truncated": blob[: len(blob) // 2],
                      "other_key": theirs.read_bytes(), "empty": b""}[damage])
    _same(stored.exported_call(scaled_sums, args, fb), scaled_sums(*args))
    assert _reads_as(mine, args), "the damaged file was not replaced"


def _reads_as(path, args) -> bool:
    """Whether `path` is the file `exported_call` would read for `args`."""
    leaves, treedef = jax.tree.flatten(args)
    arrays = [v for v in leaves if isinstance(v, jax.Array)]
    static = [None if isinstance(v, jax.Array) else v for v in leaves]
    name, digest = stored.export_key(scaled_sums, treedef, static, arrays)
    header = f"jthermo-export {digest}\n".encode()
    return path.name.startswith(name) and stored.read_export(path, header, arrays) is not None


def test_cache_off_inside_a_trace_or_unstable_key_uses_the_plain_function(folder, monkeypatch):
    args = _args()
    fb = Counting()
    monkeypatch.setitem(runtime.state, "dir", None)           # --no-cache
    _same(stored.exported_call(scaled_sums, args, fb), scaled_sums(*args))
    assert fb.calls == 1 and not folder.exists()
    monkeypatch.setitem(runtime.state, "dir", folder.parent)

    @jax.jit
    def outer(k):
        g = Gain(k=k, label="a")
        return stored.exported_call(scaled_sums, (g, jnp.arange(5.0, dtype=jnp.float32), 3),
                                     fb)["y"]

    np.testing.assert_array_equal(outer(jnp.float32(2.0)), scaled_sums(*args)["y"])
    assert fb.calls == 2 and not _files(folder)

    class Opaque:   # a static leaf whose repr names its address: no stable key
        pass

    g = Gain(k=jnp.asarray(2.0, jnp.float32), label=Opaque())
    stored.exported_call(lambda g, x: x * g.k, (g, jnp.ones(2)), lambda g, x: x * g.k)
    assert not _files(folder)


def test_unwritable_folder_still_gives_the_right_result(folder):
    folder.parent.mkdir(parents=True, exist_ok=True)
    folder.write_text("a file where the folder should be")
    args = _args()
    fb = Counting()
    for _ in range(2):
        _same(stored.exported_call(scaled_sums, args, fb), scaled_sums(*args))
    assert fb.calls == 0 and folder.is_file()


def test_least_recently_used_files_are_pruned(folder, monkeypatch):
    monkeypatch.setattr(stored, "MAX_EXPORTS", 2)
    fb = Counting()
    for n in (1, 2, 3):
        stored.exported_call(scaled_sums, _args(n=n), fb)
    assert len(_files(folder)) == 2


def test_a_jax_setting_that_shapes_the_trace_is_part_of_the_key(folder):
    fb = Counting()
    args = _args()
    stored.exported_call(scaled_sums, args, fb)
    with jax.numpy_rank_promotion("warn"):
        stored.exported_call(scaled_sums, args, fb)
    assert fb.calls == 0 and len(_files(folder)) == 2


def test_a_program_called_again_in_one_process_is_not_read_again(folder, monkeypatch):
    """The process keeps what it read or wrote: a second call neither deserializes the file nor
    traces; a file replaced on disk (another stat) is read again."""
    args = _args()
    ref = scaled_sums(*args)
    fb = Counting()
    _same(stored.exported_call(scaled_sums, args, fb), ref)

    def no_reading(*a, **k):
        raise AssertionError("read again although this process holds the program")

    monkeypatch.setattr(export, "deserialize", no_reading)
    monkeypatch.setattr(export, "export", no_reading)
    _same(stored.exported_call(scaled_sums, args, fb), ref)
    assert fb.calls == 0
    monkeypatch.undo()
    monkeypatch.setitem(runtime.state, "dir", folder.parent)
    (path,) = _files(folder)
    path.write_bytes(b"")                     # replaced: read again, found damaged, rewritten
    _same(stored.exported_call(scaled_sums, args, fb), ref)
    assert _reads_as(path, args)
