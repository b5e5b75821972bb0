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
    for c in rep["controllers"]:
        assert all(np.isfinite(c[k]) for k in ("mse", "saturated_fraction", "overshoot_C",
                                               "load_mse"))
    cfg = (calibrated / "res" / "firmware.cfg").read_text()
    assert "[extruder]" in cfg and "control: pid" in cfg
    gains = {k: float(v) for k, v in re.findall(r"^(pid_K[pid]): ([\d.]+)$", cfg, re.M)}
    ctrl = io.load_controller(calibrated / "res" / "controller.jtm")
    assert isinstance(ctrl, KlipperPID)
    assert ctrl.gains()[0] == pytest.approx(gains, abs=0)    # the file runs what was judged
    assert (calibrated / "res" / "report.md").read_text().startswith("# Heater calibration")


def test_bad_heater_exit_2(calibrated, capsys):
    rc = main(["calibrate", str(calibrated / "imp" / "extruder_seg01.csv"), "--heater", "bed",
               "--out", str(calibrated / "bad")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "--heater bed" in err
    assert not (calibrated / "bad").exists()
