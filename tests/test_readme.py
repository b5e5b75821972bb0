"""Keep the README honest: run each ```python block of README.md, in order, in one namespace."""

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _blocks():
    if not README.exists():
        return []
    text = README.read_text(encoding="utf-8")
    return [m.group(1) for m in re.finditer(r"^```python[ \t]*\n(.*?)^```", text, re.S | re.M)]


BLOCKS = _blocks()


@pytest.mark.skipif(not BLOCKS, reason="README.md has no ```python blocks")
def test_readme_python_blocks(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)          # blocks may write files: keep them out of the repo
    monkeypatch.setenv("CI", "1")        # no progress bars
    ns: dict = {"__name__": "__readme__"}
    for i, code in enumerate(BLOCKS, 1):
        try:
            exec(compile(code, f"README.md python block {i}", "exec"), ns)
        except Exception as exc:  # noqa: BLE001 - report which block broke
            pytest.fail(f"README python block {i} failed: {type(exc).__name__}: {exc}")
