"""`jthermo import`: a klippy.log the test writes (two host runs, two heaters, a gap, jittered
clock) -> one data file per heater and segment, the configuration in force beside them."""

import json

import numpy as np
import pytest

from jthermo import data
from jthermo.cli import main
from jthermo.errors import DataError
from jthermo.firmware import klippy

from . import reference as ref


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    p = tmp_path_factory.mktemp("log") / "klippy.log"
    ref.simulated_log(p, seconds=(300, 200), gap_after=150)
    return p


def test_segments_split_at_gap_and_restart(log):
    parsed = klippy.read_klippy_log(log)
    assert parsed.version == "v0.12.0-1-gabcdef"
    by = {h: [s for s in parsed.segments if s.heater == h] for h in ("extruder", "heater_bed")}
    for h, segs in by.items():
        # run 1 split by the 10 s hole; run 2 on its own (its temp=0.0 first line dropped)
        assert len(segs) == 3, (h, [s.lines for s in segs])
        for s in segs:
            steps = np.round(np.diff(s.t), 1)
            assert set(steps.tolist()) <= {1.0, 1.1} and s.t[0] == 0.0
            assert np.all(s.y > 0)
    bed = by["heater_bed"][0].config
    assert bed["control"] == "pid" and bed["pid_kp"] == 60.0 and bed["max_power"] == 0.8
    ext = by["extruder"][0].config
    assert ext["max_power"] == 1.0 and "max_power" in ext["defaults"] and ext["smooth_time"] == 1.0


def test_cli_import_writes_loadable_files(log, tmp_path):
    out = tmp_path / "out"
    rc = main(["import", str(log), "--out", str(out), "--json", str(tmp_path / "r.json"),
               "--quiet"])
    assert rc == 0
    rep = json.loads((out / klippy.SUMMARY_NAME).read_text())
    assert rep["files"] and json.loads((tmp_path / "r.json").read_text())["files"] == rep["files"]
    written = [s for s in rep["segments"] if s["file"]]
    assert {s["heater"] for s in written} == {"extruder", "heater_bed"}
    assert all(s["duration_s"] >= klippy.MIN_DURATION_S for s in written)
    f = out / written[0]["file"]
    d = data.load(f)
    h = written[0]["heater"]
    assert d.input_names == (h,) and d.output_names == (h,) and d.signal_names == (f"{h}_target",)
    assert d.ts == 1.0 and any("re-gridded" in n for n in d.notes)
    cfg = klippy.config_for(f)
    assert cfg["heater"] == h and cfg["control"] == "pid"


def test_excitation_is_said(tmp_path):
    t = np.arange(100.0)
    hold = klippy.Segment("extruder", t, 0.3 + 0.01 * np.cos(t), 200 + 0.1 * np.sin(t),
                          np.full(100, 200.0), (1, 100), 0.0)
    assert "too little excitation" in hold.excitation()
    flat = klippy.Segment("extruder", t, np.full(100, 0.3), 200 + 0.1 * np.sin(t),
                          np.full(100, 200.0), (1, 100), 0.0)
    assert "no excitation" in flat.excitation()
    step = klippy.Segment("extruder", t, 0.3 + 0.01 * np.cos(t), 150 + 0.5 * t,
                          np.where(t < 50, 150.0, 200.0), (1, 100), 0.0)
    assert step.excitation() is None


@pytest.mark.parametrize("kind", ["truncated", "no_heaters", "missing_heater"])
def test_bad_logs_exit_2_with_one_line(kind, tmp_path, capsys):
    p = tmp_path / "klippy.log"
    if kind == "truncated":
        ref.simulated_log(p, seconds=(80,), truncate=True)
    elif kind == "no_heaters":
        p.write_text("Starting Klippy...\nStats 1.0: gcodein=0 mcu: mcu_awake=0.001\n"
                     "Stats 2.0: gcodein=0 mcu: mcu_awake=0.001\n")
    else:
        ref.simulated_log(p, seconds=(80,))
        lines = p.read_text().splitlines()
        i = max(j for j, s in enumerate(lines) if s.startswith("Stats"))
        lines[i] = lines[i].split(" heater_bed:")[0]
        p.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    rc = main(["import", str(p), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and err.startswith("jthermo: error:")
    assert not out.exists()                         # nothing half-written
    with pytest.raises(DataError):
        klippy.read_klippy_log(p)
