"""Markdown reports: tables, figures and the sections that the demo, `fit` and `simulate` write.

A `Report` collects Markdown blocks and writes them atomically; figures are referenced by
paths relative to the report, so the folder can be moved or published as it is.

```python
rep = Report("Identification")
rep.table([{"family": "arx", "fit %": 91.2}], ["family", "fit %"])
rep.figure("figures/compare.png", "Measured and simulated outputs")
rep.write("runs/demo/report.md")
```
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any


def fmt(v: Any, digits: int = 4) -> str:
    """A table cell: floats to `digits` significant figures, None/NaN as an em dash."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if not math.isfinite(v):
            return "—"
        return f"{v:.{digits}g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(fmt(x, digits) for x in v)
    if isinstance(v, dict):
        return ", ".join(f"{k}={fmt(x, digits)}" for k, x in v.items())
    try:  # numpy / jax scalars
        return fmt(float(v), digits)
    except (TypeError, ValueError):
        return str(v).replace("|", "\\|").replace("\n", " ")


def markdown_table(rows: Iterable[dict], columns: Sequence[str] | None = None,
                   headers: Sequence[str] | None = None, digits: int = 4) -> str:
    """A GitHub-flavoured Markdown table of `rows` (dicts) over `columns`."""
    rows = list(rows)
    if columns is None:
        columns = list(dict.fromkeys(k for r in rows for k in r))
    headers = list(headers) if headers is not None else list(columns)
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join(" --- " for _ in headers) + "|"]
    for r in rows:
        lines.append("| " + " | ".join(fmt(r.get(c), digits) for c in columns) + " |")
    return "\n".join(lines)


class Report:
    """Markdown blocks, written atomically with `write`; figure paths are made relative."""

    def __init__(self, title: str | None = None):
        self.blocks: list[str] = []
        self._figures: list[tuple[int, Path, str]] = []
        if title:
            self.blocks.append(f"# {title}")

    def heading(self, text: str, level: int = 2) -> "Report":
        self.blocks.append("#" * level + " " + text)
        return self

    def para(self, text: str) -> "Report":
        self.blocks.append(text.strip())
        return self

    def bullets(self, items: Iterable[str]) -> "Report":
        self.blocks.append("\n".join(f"- {i}" for i in items))
        return self

    def table(self, rows: Iterable[dict], columns: Sequence[str] | None = None,
              headers: Sequence[str] | None = None, digits: int = 4) -> "Report":
        self.blocks.append(markdown_table(rows, columns, headers, digits))
        return self

    def figure(self, path: str | os.PathLike, caption: str = "") -> "Report":
        """Reference a figure (made relative to the report's folder when written)."""
        self._figures.append((len(self.blocks), Path(path), caption))
        self.blocks.append("")  # placeholder, filled in `render`
        return self

    def code(self, text: str, lang: str = "") -> "Report":
        self.blocks.append(f"```{lang}\n{text.rstrip()}\n```")
        return self

    def render(self, base: str | os.PathLike | None = None) -> str:
        blocks = list(self.blocks)
        for i, p, caption in self._figures:
            rel = p
            if base is not None:
                try:
                    rel = Path(os.path.relpath(p.resolve(), Path(base).resolve()))
                except ValueError:  # another drive
                    rel = p
            alt = caption or p.stem
            blocks[i] = f"![{alt}]({rel.as_posix()})" + (f"\n\n*{caption}*" if caption else "")
        return "\n\n".join(b for b in blocks if b != "") + "\n"

    def write(self, path: str | os.PathLike) -> Path:
        from ._files import atomic_write_text

        p = Path(path)
        atomic_write_text(p, self.render(p.parent))
        return p


# ---------------------------------------------------------------- sections


def fit_section(rep: Report, fits: Sequence[dict], *, level: int = 2) -> Report:
    """Rows of `jthermo fit` reports (or the demo's): family, orders, fit % per output, time."""
    rep.heading("Identification", level)
    rows = [{"family": f.get("model"), "orders": f.get("orders") or "—",
             "fit % (per output)": [round(x, 1) for x in f.get("fit_percent", [])],
             "mean fit %": f.get("mean_fit_percent"), "converged": f.get("converged"),
             "seconds": f.get("seconds")} for f in fits]
    return rep.table(rows, digits=4)


def simulate_section(rep: Report, runs: Sequence[dict], *, level: int = 2,
                     metrics: Sequence[str] = ("mse", "max_neighbour_diff_C", "time_outside_window_s",
                                               "overshoot_C", "settling_time_s", "mean_input")) -> Report:
    """Rows of `jthermo simulate` reports: scenario, controller and the chosen metrics."""
    rep.heading("Closed loop", level)
    rows = [{"scenario": r.get("scenario"), "controller": r.get("controller"),
             **{m: r.get("metrics", {}).get(m) for m in metrics}} for r in runs]
    return rep.table(rows, ["scenario", "controller", *metrics])
