"""`jthermo import` of a klippy.log the test writes -> `jthermo calibrate` -> the firmware
file, cheap: a short record, a few tuning steps."""

import json
import re

import numpy as np
import pytest

from jthermo import io
from jthermo.cli import main
from jthermo.firmware.pid import KlipperPID

from . import reference as ref


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    root = tmp_path_factory.mktemp("cal")
    ref.simulated_log(root / "klippy.log", seconds=(500, 300), heaters=("extruder",))
    assert main(["import", str(root / "klippy.log"), "--out", str(root / "imp"), "--quiet"]) == 0
    rc = main(["calibrate", str(root / "imp" / "extruder_seg01.csv"), "--validation",
               str(root / "imp" / "extruder_seg02.csv"), "--out", str(root / "res"),
               "--steps", "2", "--rollouts", "1", "--json", str(root / "r.json"), "--quiet"])
    assert rc == 0
    return root


def test_firmware_file_and_report(calibrated):
    rep = json.loads((calibrated / "r.json").read_text())
    assert set(rep) >= {"model", "setpoints", "finding", "controllers", "floor_plus_noise",
                        "firmware"}
    assert set(rep["model"]) >= {"family", "orders", "validation_fit_percent"}
    assert rep["setpoints"] == [200.0]                     # the log's most common target
    names = {c["name"]: c for c in rep["controllers"]}
    assert names["firmware_pid"]["kind"] == "firmware_pid"
    assert names["printer_config"]["kind"] == "yardstick"   # the gains the printer ran with
    assert rep["mpc"] is not None                            # one hot end: the two-state fit
    assert names["firmware_mpc"]["kind"] == "firmware_mpc"   # and the firmware's MPC judged
    for c in rep["controllers"]:
        assert all(np.isfinite(c[k]) for k in ("mse", "saturated_fraction", "overshoot_C",
                                               "load_mse"))
    cfg = (calibrated / "res" / "firmware.cfg").read_text()
    assert "[extruder]" in cfg and "control: pid" in cfg
    gains = {k: float(v) for k, v in re.findall(r"^(pid_K[pid]|smooth_time): ([\d.]+)$", cfg,
                                                re.MULTILINE)}
    ctrl = io.load_controller(calibrated / "res" / "controller.jtm")
    assert isinstance(ctrl, KlipperPID)
    assert ctrl.gains()[0] == pytest.approx(gains, abs=0)    # the file runs what was judged
    md = (calibrated / "res" / "report.md").read_text()
    assert md.startswith("# Heater calibration")
    assert f"Diagnosis: {rep['finding']}" in md and rep["finding"] and rep["verdict"]
    for name in rep["figures"].values():                     # every figure written and linked
        assert (calibrated / "res" / name).stat().st_size > 0 and f"]({name})" in md
    assert set(rep["figures"]) == {"fit", "step", "startup", "changes", "comparison"}
    assert rep["load"]["what"] and np.isfinite(rep["load"]["firmware_pid_load_mse"])
    assert isinstance(rep["supported"], bool)
    assert rep["supported"] == (rep["why_not"] is None)
    assert ("Not a tuning to use" in md) == (not rep["supported"])
    assert ("NOT A TUNING TO USE" in cfg) == (not rep["supported"])


def test_stage_timing(calibrated):
    """`--json` times every stage, in the order they ran; the main thread's stages fit in the
    command's wall time and the judging plant's fit and the diagnosis (their own threads) are
    timed apart."""
    t = json.loads((calibrated / "r.json").read_text())["timing"]
    names = [s["stage"] for s in t["stages"]]
    assert names == ["records", "fit arx", "fit oe", "two-state fit", "relay tests", "tuning",
                     "yardstick designs", "waiting for the judging plant",
                     "fit of the validation record (its thread)", "judgement", "floor + noise",
                     "files and figures", "waiting for the diagnosis", "diagnosis (its thread)"]
    main_thread = [s for s in t["stages"] if s["cpu_s"] is not None]
    for s in t["stages"]:
        assert s["wall_s"] >= 0 and s["thread_cpu_s"] >= 0
    assert sum(s["wall_s"] for s in main_thread) <= t["total"]["wall_s"] + 1e-2
    assert sum(s["compile_s"] for s in main_thread) > 0      # a cold or cached run compiles
    assert t["stages"][-1]["wall_s"] > 0 and t["total"]["cpu_s"] > 0


def test_marlin_file_has_mpc_line(calibrated):
    """One heater: the two-state model is fitted and its M306 line is in Marlin's file."""
    root = calibrated
    assert main(["calibrate", str(root / "imp" / "extruder_seg01.csv"), "--out",
                 str(root / "marlin"), "--firmware", "marlin", "--steps", "0", "--rollouts", "1",
                 "--heater-power", "50", "--json", str(root / "m.json"), "--quiet"]) == 0
    rep = json.loads((root / "m.json").read_text())
    text = (root / "marlin" / "firmware.gcode").read_text()
    assert re.search(r"^M301 E0 P[\d.]+ I[\d.]+ D[\d.]+ ; extruder$", text, re.MULTILINE)
    assert rep["mpc"]["constants"]["heater_power"] == 50.0
    m = re.search(r"M306 E0 P50 C([\d.e+-]+) R([\d.e+-]+) A([\d.e+-]+) F", text)
    assert m and float(m.group(1)) == pytest.approx(rep["mpc"]["constants"]["block_heat_capacity"])
    assert float(m.group(2)) > 0 and text.rstrip().endswith("M500")
    tau = rep["gains"]["firmware_pid"][0]["smooth_time"]
    assert re.search(rf"^; .*smooth_time: extruder {tau:g} s\) has no M301", text, re.MULTILINE)


def test_c_file_carries_the_note(calibrated):
    """The C export starts with the calibration's note, which says first when the result is
    not a tuning to use (as the other firmware files do)."""
    root = calibrated
    assert main(["calibrate", str(root / "imp" / "extruder_seg01.csv"), "--out", str(root / "c"),
                 "--firmware", "c", "--steps", "0", "--rollouts", "1", "--json",
                 str(root / "c.json"), "--quiet"]) == 0
    rep = json.loads((root / "c.json").read_text())
    text = (root / "c" / "firmware.c").read_text()
    head = text.splitlines()[0]
    assert head.startswith("/* NOT A TUNING TO USE: " if not rep["supported"]
                           else "/* jthermo calibrate: ")
    assert ("NOT A TUNING TO USE" in text) == (not rep["supported"])
    assert "double jthermo_heater_update(" in text


def test_bad_heater_exit_2(calibrated, capsys):
    rc = main(["calibrate", str(calibrated / "imp" / "extruder_seg01.csv"), "--heater", "bed",
               "--out", str(calibrated / "bad")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "--heater bed" in err
    assert not (calibrated / "bad").exists()


def test_unreachable_setpoint_exit_2_before_the_diagnosis(calibrated, capsys, monkeypatch):
    """A set point no fitted model reaches is one line and exit 2, found before the diagnosis
    starts beside the fits (nothing waits for it) and before anything is written."""
    from jthermo.firmware import calibrate as cal

    started = []
    monkeypatch.setattr(cal, "_diagnosis", lambda *a: started.append(a))
    rc = main(["calibrate", str(calibrated / "imp" / "extruder_seg01.csv"), "--validation",
               str(calibrated / "imp" / "extruder_seg02.csv"), "--setpoint", "5000",
               "--out", str(calibrated / "unreachable"), "--steps", "0", "--rollouts", "1", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "beyond reach" in err
    assert not (calibrated / "unreachable").exists() and started == []


@pytest.mark.parametrize("n", [1, 16])
def test_disagreeing_records_are_not_a_tuning(n):
    """Design and judging models whose relay tests are far apart in K_u (one with ten times
    the other's): the tuning is said to be unsupported; the same model agrees with itself."""
    from jthermo.control.design import design_point
    from jthermo.firmware import judging
    from jthermo.firmware.pid import pid_calibrate
    from jthermo.firmware.tuning import ultimate
    from jthermo.models import StateSpace

    from .test_pid_law import hotend

    a = hotend(n=n)
    b = StateSpace(a.A, 10.0 * np.asarray(a.B), a.C, ts=a.ts, u0=np.full(n, 0.07),
                   y0=a.y0)                      # the same equilibria, ten times the gain
    r = np.full(n, 200.0)
    ku, tu = ultimate([pid_calibrate(design_point(a, setpoint=r), 200.0, i) for i in range(n)])
    assert judging.agreement(ku, tu, a, a, r, 1.0) is None
    text = judging.agreement(ku, tu, b, a, r, 1.0)
    assert text and "disagree" in text
    ok = {"mse": 1.0, "saturated_fraction": 0.1, "overshoot_C": 0.5, "load_mse": 1.0,
          "load_saturated_fraction": 0.0}
    assert judging.why_not(None, ok) is None
    assert "overshoots" in judging.why_not(None, {**ok, "overshoot_C": 2.0})
    assert "input limit" in judging.why_not(None, {**ok, "load_saturated_fraction": 0.5})
    assert judging.why_not(text, ok).startswith("the estimation and validation records disagree")
