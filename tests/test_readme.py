"""Keep the README and the documentation honest: run their Python tours, and check that every
file they link or every study script they cite exists, that the README stays short, and that
they speak of the project, not of how it was made."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
#: pages whose ```python blocks run as they are (the others show fragments of a session)
RUNNABLE = [README, DOCS / "guides" / "sweeps.md"]
#: hand-written pages (the generated ones are rewritten by `python docs/gen_pages.py`)
WRITTEN = [README, DOCS / "index.md", *sorted((DOCS / "guides").glob("*.md"))]
README_LIMIT = 15 * 1024
NOT_ABOUT_THE_PROJECT = re.compile(
    r"session [0-9]|_s[0-9]{2}\b|issue [0-9]|helpers? (stopped|session)|the[ ]lead\b"
    r"|\b20[0-9]{2}-[01][0-9]-[0-3][0-9]\b|\bload [0-9]", re.IGNORECASE)
LINK = re.compile(r"\]\(([^)#\s]+)(#[^)\s]*)?\)")
SCRIPT = re.compile(r"\b(?:python|bash) +((?:experiments|benchmarks|docs)/[\w./-]+\.(?:py|sh))")


def python_blocks(path: Path) -> list[str]:
    text = path.read_text(encoding="utf-8")
    return [m.group(1) for m in re.finditer(r"^```python[ \t]*\n(.*?)^```", text, re.DOTALL | re.MULTILINE)]


def test_python_blocks_are_found(tmp_path):
    assert python_blocks(README), "README.md has no ```python blocks"
    page = tmp_path / "page.md"
    page.write_text("```python\nx = 1\n```\nprose\n```bash\nls\n```\n```python\ny = 2\n```\n",
                    encoding="utf-8")
    assert python_blocks(page) == ["x = 1\n", "y = 2\n"]


@pytest.mark.parametrize("page", RUNNABLE, ids=lambda p: str(p.relative_to(ROOT)))
def test_python_blocks_run(page, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)          # blocks may write files: keep them out of the repo
    monkeypatch.setenv("CI", "1")        # no progress bars
    ns: dict = {"__name__": "__readme__"}
    for i, code in enumerate(python_blocks(page), 1):
        try:
            exec(compile(code, f"{page.name} python block {i}", "exec"), ns)  # noqa: S102
        except Exception as exc:  # noqa: BLE001 - report which block broke
            pytest.fail(f"{page.name} python block {i} failed: {type(exc).__name__}: {exc}")


def test_readme_is_short():
    size = len(README.read_bytes())
    assert size <= README_LIMIT, f"README.md is {size} bytes, over {README_LIMIT}: move detail to docs/"


@pytest.mark.parametrize("page", WRITTEN, ids=lambda p: str(p.relative_to(ROOT)))
def test_links_and_cited_scripts_exist(page):
    text = page.read_text(encoding="utf-8")
    missing = []
    for target, _ in LINK.findall(text):
        if re.match(r"[a-z]+://", target):
            continue
        if not (page.parent / target).exists():
            missing.append(target)
    for script in SCRIPT.findall(text):
        if not (ROOT / script).exists():
            missing.append(script)
    assert not missing, f"{page.relative_to(ROOT)} names files that do not exist: {missing}"


@pytest.mark.parametrize("page", WRITTEN, ids=lambda p: str(p.relative_to(ROOT)))
def test_pages_speak_of_the_project_only(page):
    hits = [line.strip() for line in page.read_text(encoding="utf-8").splitlines()
            if NOT_ABOUT_THE_PROJECT.search(line)]
    assert not hits, f"{page.relative_to(ROOT)}: {hits[:3]}"


def test_the_checks_can_fail():
    """The patterns above catch what they are meant to catch (the strings are split so that
    this file itself passes the tree-wide search for such words)."""
    assert NOT_ABOUT_THE_PROJECT.search("measured in " + "session" + " 12")
    assert NOT_ABOUT_THE_PROJECT.search("at load" + " 1.4")
    assert NOT_ABOUT_THE_PROJECT.search("see results_s" + "31.md")
    assert NOT_ABOUT_THE_PROJECT.search("as " + "the" + " lead said")
    assert NOT_ABOUT_THE_PROJECT.search("on 2026-11-28")
    assert not NOT_ABOUT_THE_PROJECT.search("a load of random sign; 16 sessions of 3600 s")
    assert LINK.findall("[a](docs/x.md#y) and [b](https://e.org)") == [
        ("docs/x.md", "#y"), ("https://e.org", "")]
    assert SCRIPT.findall("`python experiments/own_plant.py --steps 60`, `bash b/x.sh`") == [
        "experiments/own_plant.py"]
