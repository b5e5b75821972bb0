"""Klipper's `klippy.log` as records: every heater's `Stats` fields, split into contiguous
segments, and the heater configuration in force from the log's config dumps.

**What the log holds** (Klipper `klippy/extras/heaters.py`, `Heater.stats`): about once a
second a `Stats <clock>:` line carries, per heater, `<name>: target=%.0f temp=%.1f pwm=%.3f`,
the set point (°C), the last sensor reading (°C) and the last duty sent to the heater
(0..`max_power`). `<name>` is the section's last word (`[heater_generic chamber]` -> `chamber`).
The clock is the host's monotonic time in s, printed to 0.1 s; the timer is re-armed at
"now + 1 s", so steps are 1.0 s or 1.1 s. Each start of the host program (`Start printer at`)
prints the whole configuration between `===== Config file =====` and a line of `=`.

**Segments.** A heater's samples are split where the host restarts (its controller's state
restarts), where the clock steps back or by more than `MAX_GAP_S` (Stats lines are written only
while something is active: idle stretches are absent, not zero), and rows with `temp=0.0` (the
sensor not yet read after a start) are left out. The time stamps are written as logged,
relative to the segment's first line: the data loader re-grids the 1.0 / 1.1 s jitter onto a
uniform Ts and says so (DESIGN.md's data contract).

**Refused** (`DataError`, one line): a log without a heater's `Stats` fields; a `Stats` line
that stops inside a heater's fields or lacks a heater the run's other lines carry (a truncated
or corrupted line), naming its line number.
"""

from __future__ import annotations

import gzip
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError

#: a longer step between two Stats lines splits a segment, s (the data loader bridges at most
#: three missing samples, `data.MAX_GAP_SAMPLES`)
MAX_GAP_S = 3.0
#: segments shorter than this are listed in the import's summary, not written, s
MIN_DURATION_S = 60.0
#: a segment whose temperature spans less than this and whose set point never changes holds one
#: temperature: too little excitation to identify a heater from, °C
MIN_RANGE_C = 5.0

_STATS = re.compile(r"^Stats (\d+(?:\.\d+)?):")
_GROUP = re.compile(r"(?:^|\s)(\S+): target=")
_FIELDS = re.compile(r"target=(-?\d+) temp=(-?\d+\.\d) pwm=(-?\d+\.\d{3})(?=\s|$)")
_RESTART = ("Start printer at", "Restarting printer", "Starting Klippy")
_CONFIG_START = "===== Config file ====="
_AUTOTUNE = re.compile(r"Autotune: final: Kp=(\S+) Ki=(\S+) Kd=(\S+)")
_VERSION = re.compile(r"^Git version: '?([^'\s]+)")
#: heater options kept in the summary (Klipper's config names, lower case as it prints them)
HEATER_KEYS = ("control", "pid_kp", "pid_ki", "pid_kd", "max_power", "smooth_time",
               "max_delta", "pwm_cycle_time", "sensor_type", "min_temp", "max_temp",
               "heater_power", "block_heat_capacity", "sensor_responsiveness",
               "ambient_transfer", "fan_ambient_transfer")
#: Klipper's defaults for the options the controller uses (`heaters.py`)
DEFAULTS = {"max_power": 1.0, "smooth_time": 1.0, "max_delta": 2.0, "pwm_cycle_time": 0.1}


@dataclass
class Segment:
    """One heater's contiguous samples: `t` s from the first, `u` duty, `y` °C, `target` °C;
    `lines` the log line numbers of the first and last sample; `start` the Stats clock (s)."""

    heater: str
    t: np.ndarray
    u: np.ndarray
    y: np.ndarray
    target: np.ndarray
    lines: tuple[int, int]
    start: float
    config: dict = field(default_factory=dict)
    autotune: list = field(default_factory=list)

    @property
    def duration(self) -> float:
        return float(self.t[-1]) if self.t.size else 0.0

    def excitation(self) -> str | None:
        """None when the segment moves enough to identify from, else why not."""
        span = float(np.ptp(self.y))
        changes = int(np.count_nonzero(np.diff(self.target)))
        if float(np.ptp(self.u)) == 0.0:
            return f"the duty never changes ({float(self.u[0]):.3f}): no excitation"
        if span < MIN_RANGE_C and changes == 0:
            return (f"holds one set point within {span:.1f} °C (under {MIN_RANGE_C:g} °C, no "
                    "set-point change): too little excitation to identify from")
        return None


@dataclass
class KlippyLog:
    """A parsed log: its `segments` (all lengths), the `configs` dumped (line, {section: {key:
    value}}), the Klipper `version` and the number of `stats_lines`."""

    source: str
    segments: list[Segment]
    configs: list[tuple[int, dict]]
    version: str | None
    stats_lines: int


def _read_lines(path: Path) -> list[str]:
    if not path.exists():
        raise DataError(f"{path}: no such file")
    if path.is_dir():
        raise DataError(f"{path}: is a directory, not a klippy.log")
    raw = path.read_bytes()
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError):
            raise DataError(f"{path}: a truncated or corrupt gzip file") from None
    if b"\x00" in raw:
        raise DataError(f"{path}: binary content, not a klippy.log")
    return raw.decode("utf-8", errors="replace").splitlines()


def _parse_config(lines: list[str], i: int) -> tuple[dict, int]:
    """The config dump that starts after line index `i`: `{section: {key: value}}` and the index
    of its closing line."""
    sections: dict[str, dict] = {}
    current = None
    j = i + 1
    while j < len(lines) and not re.fullmatch(r"=+", lines[j].strip()):
        s = lines[j]
        m = re.match(r"^\[([^\]]+)\]\s*$", s)
        if m:
            current = sections.setdefault(m.group(1).strip(), {})
        elif current is not None and s and not s[0].isspace() and not s.startswith("#"):
            m = re.match(r"^([^=:]+?)\s*[=:]\s*(.*)$", s)
            if m:
                current[m.group(1).strip().lower()] = m.group(2).strip()
        j += 1
    return sections, j


def heater_section(sections: dict, heater: str) -> dict:
    """The config section of the heater whose Stats name is `heater` (the section name's last
    word); {} when the dump has none."""
    for name, opts in sections.items():
        if name.split()[-1] == heater and ("heater_pin" in opts or "control" in opts):
            return opts
    return {}


def _number(text: str | None):
    try:
        v = float(text)
    except (TypeError, ValueError):
        return text
    return v if math.isfinite(v) else text


def heater_config(sections: dict, heater: str) -> dict:
    """The options of `HEATER_KEYS` the heater's section sets, numbers as numbers, with
    Klipper's defaults for `max_power`, `smooth_time`, `max_delta` and `pwm_cycle_time` filled in
    (`defaults` lists which were filled)."""
    opts = heater_section(sections, heater)
    out = {k: _number(opts[k]) for k in HEATER_KEYS if k in opts}
    filled = [k for k in DEFAULTS if k not in out]
    out.update({k: DEFAULTS[k] for k in filled})
    out["defaults"] = filled
    return out


def _split(heater, rows, configs) -> list[Segment]:
    """Rows `(clock, target, temp, pwm, line, run)` of one heater -> segments."""
    segs, cur = [], []

    def close():
        if cur:
            a = np.array([r[:4] for r in cur], np.float64)
            t = np.round(a[:, 0] - a[0, 0], 1)
            line0 = cur[0][4]
            cfg = next((c for ln, c in reversed(configs) if ln < line0), {})
            segs.append(Segment(heater, t, a[:, 3], a[:, 2], a[:, 1], (line0, cur[-1][4]),
                                float(a[0, 0]), heater_config(cfg, heater)))

    for r in rows:
        if r[2] == 0.0:          # sensor not read yet
            close()
            cur = []
            continue
        if cur and (r[5] != cur[-1][5] or not 0.0 < r[0] - cur[-1][0] <= MAX_GAP_S):
            close()
            cur = []
        cur.append(r)
    close()
    return segs


def read_klippy_log(path) -> KlippyLog:
    """Parse a `klippy.log` (plain or gzip) into heater segments and config dumps."""
    path = Path(path)
    lines = _read_lines(path)
    configs: list[tuple[int, dict]] = []
    rows: dict[str, list] = {}
    autotune: list[tuple[int, tuple]] = []
    version, run, n_stats = None, 0, 0
    expected: set[str] | None = None
    i = 0
    while i < len(lines):
        s = lines[i]
        ln = i + 1
        if s.startswith(_CONFIG_START):
            sections, i = _parse_config(lines, i)
            configs.append((ln, sections))
            i += 1
            continue
        if s.startswith(_RESTART):
            run += 1
            expected = None
        m = _STATS.match(s)
        if m:
            n_stats += 1
            clock = float(m.group(1))
            names = [g.group(1) for g in _GROUP.finditer(s)]
            found = {}
            for g in _GROUP.finditer(s):
                f = _FIELDS.match(s, g.end() - len("target="))
                if f is None:
                    raise DataError(f"{path}: line {ln}: the Stats fields of `{g.group(1)}` are "
                                    "cut off or malformed (a truncated line)")
                found[g.group(1)] = tuple(float(x) for x in f.groups())
            if expected is not None and names and not expected <= set(names):
                missing = min(expected - set(names))
                raise DataError(f"{path}: line {ln}: the Stats line lacks heater `{missing}` that "
                                "the run's other lines carry (a truncated line)")
            if names:
                expected = set(names) if expected is None else expected | set(names)
            for name, (target, temp, pwm) in found.items():
                rows.setdefault(name, []).append((clock, target, temp, pwm, ln, run))
        else:
            a = _AUTOTUNE.search(s)
            if a:
                autotune.append((ln, tuple(float(x) for x in a.groups())))
            v = _VERSION.match(s)
            if v and version is None:
                version = v.group(1)
        i += 1
    if not rows:
        what = "no Stats lines" if n_stats == 0 else f"{n_stats} Stats lines"
        raise DataError(f"{path}: {what} with a heater's fields (target=, temp=, pwm=): "
                        "not a klippy.log with heater data")
    segments = [seg for name in rows for seg in _split(name, rows[name], configs)]
    for seg in segments:
        seg.autotune = [{"line": ln, "pid_Kp": g[0], "pid_Ki": g[1], "pid_Kd": g[2]}
                        for ln, g in autotune if seg.lines[0] <= ln <= seg.lines[1] + 5]
    if not segments:
        raise DataError(f"{path}: every heater line reads temp=0.0 (no sensor reading)")
    return KlippyLog(str(path), segments, configs, version, n_stats)


def segment_csv(seg: Segment) -> str:
    """The segment as a data file: `t`, `u_<heater>` (duty), `y_<heater>` (°C),
    `w_<heater>_target` (°C, the logged set point: neither an input nor an output)."""
    h = seg.heater
    out = [f"t,u_{h},y_{h},w_{h}_target"]
    out += [f"{t:.1f},{u:.3f},{y:.1f},{r:.0f}" for t, u, y, r in
            zip(seg.t, seg.u, seg.y, seg.target)]
    return "\n".join(out) + "\n"


def summary(seg: Segment, file: str | None) -> dict:
    """What the import says of one segment (JSON-ready)."""
    dt = np.diff(seg.t)
    targets = sorted({float(x) for x in seg.target})
    return {"file": file, "heater": seg.heater, "log_lines": list(seg.lines),
            "stats_clock_s": seg.start, "duration_s": seg.duration, "samples": int(seg.t.size),
            "ts_median_s": float(np.median(dt)) if dt.size else None,
            "temp_range_C": [float(seg.y.min()), float(seg.y.max())],
            "pwm_max": float(seg.u.max()), "targets_C": targets,
            "target_changes": int(np.count_nonzero(np.diff(seg.target))),
            "excitation": seg.excitation() or "enough",
            "pid_calibrate": bool(seg.autotune), "autotune": seg.autotune,
            "config": seg.config}


#: the import's summary, beside the data files
SUMMARY_NAME = "klippy_import.json"


def import_log(path, out, *, min_duration: float = MIN_DURATION_S) -> dict:
    """Read `path` and write into folder `out` one data file per heater and segment of at least
    `min_duration` s (`<heater>_segNN.csv`, `segment_csv`) and `SUMMARY_NAME`: the log's
    Klipper version, every segment (`summary`: written or why not, excitation, the heater
    configuration in force with its control and gains). Everything is parsed and checked before
    the first file is written; files are written atomically. Returns the summary."""
    import json

    from .._files import atomic_write_text

    log = read_klippy_log(path)
    out = Path(out)
    counts: dict[str, int] = {}
    rows, files = [], []
    for seg in log.segments:
        name = None
        if seg.duration >= min_duration:
            counts[seg.heater] = counts.get(seg.heater, 0) + 1
            name = f"{seg.heater}_seg{counts[seg.heater]:02d}.csv"
            files.append((name, segment_csv(seg)))
        row = summary(seg, name)
        if name is None:
            row["skipped"] = f"shorter than {min_duration:g} s"
        rows.append(row)
    if not files:
        longest = max(s.duration for s in log.segments)
        raise DataError(f"{path}: no heater segment lasts {min_duration:g} s (the longest "
                        f"{longest:g} s)")
    heaters = sorted({s.heater for s in log.segments})
    report = {"source": str(path), "klipper_version": log.version,
              "stats_lines": log.stats_lines, "heaters": heaters,
              "files": [n for n, _ in files], "segments": rows,
              "columns": {"u_<heater>": "duty sent to the heater, 0..max_power",
                          "y_<heater>": "sensor temperature, °C",
                          "w_<heater>_target": "set point, °C (neither input nor output)"}}
    out.mkdir(parents=True, exist_ok=True)
    for name, text in files:
        atomic_write_text(out / name, text)
    atomic_write_text(out / SUMMARY_NAME, json.dumps(report, indent=1))
    return report


def config_for(data_file) -> dict | None:
    """The heater configuration in force while `data_file` (written by `import_log`) was
    recorded, from the `SUMMARY_NAME` beside it; None when there is none."""
    import json

    p = Path(data_file)
    side = p.parent / SUMMARY_NAME
    if not side.is_file():
        return None
    try:
        rep = json.loads(side.read_text())
        return next((dict(s["config"], heater=s["heater"]) for s in rep["segments"]
                     if s.get("file") == p.name), None)
    except (ValueError, KeyError, TypeError):
        return None


__all__ = [
    "DEFAULTS",
    "HEATER_KEYS",
    "MAX_GAP_S",
    "MIN_DURATION_S",
    "MIN_RANGE_C",
    "SUMMARY_NAME",
    "KlippyLog",
    "Segment",
    "config_for",
    "heater_config",
    "import_log",
    "read_klippy_log",
    "segment_csv",
    "summary",
]
