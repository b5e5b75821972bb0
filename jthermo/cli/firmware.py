"""`jthermo import` (a printer's log as data files) and `jthermo calibrate` (records to the
settings a printer's firmware runs)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import ConfigError
from .common import add_common, info, input_file, output_path, write_report

FIRMWARES = ("klipper", "marlin", "kalico", "c")


def add_parsers(sub) -> None:
    sp = sub.add_parser("import", help="a klippy.log as one data file per heater and segment")
    sp.add_argument("log", metavar="LOG", help="Klipper's klippy.log (plain or .gz)")
    sp.add_argument("--out", required=True, metavar="DIR", help="directory to write into")
    sp.add_argument("--min-duration", type=float, default=None, metavar="S",
                    help="shortest segment written, s (default 60)")
    add_common(sp, plot=False)

    sp = sub.add_parser("calibrate", help="records -> a tuned firmware PID and its settings")
    sp.add_argument("data", metavar="EST", help="estimation record (CSV), e.g. from `jthermo import`")
    sp.add_argument("--validation", metavar="VAL", help="validation record (default: the last "
                    "part of EST, held back)")
    sp.add_argument("--out", required=True, metavar="DIR", help="directory to write into")
    sp.add_argument("--firmware", choices=FIRMWARES, default="klipper",
                    help="settings to write (default klipper)")
    sp.add_argument("--heater", metavar="NAME", help="the heater (output) to calibrate "
                    "(default: the record's only one)")
    sp.add_argument("--setpoint", type=float, metavar="C", help="set point, °C (default: the "
                    "record's most common target, else its operating point)")
    sp.add_argument("--steps", type=int, default=None, metavar="K",
                    help="compass-search iterations at most after the grid of starts (default 20; it stops once converged)")
    sp.add_argument("--rollouts", type=int, default=None, metavar="B",
                    help="rollouts per scenario (default 4)")
    sp.add_argument("--heater-power", type=float, default=None, metavar="W",
                    help="the heater's rated power, W, the scale of the MPC constants "
                    "(default 40, Marlin's MPC_HEATER_POWER)")
    sp.add_argument("--oracle", action="store_true", help="also tune the firmware PID on the "
                    "judging plant itself: what a PID reaches where the plant is known (a "
                    "measure of the data, not a tuning to use)")
    add_common(sp, plot=False)


def _out_dir(path: str) -> Path:
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a directory")
    return out


def cmd_import(args: argparse.Namespace) -> dict:
    from ..firmware import klippy

    input_file(args.log, "LOG")
    js = output_path(args.json, "--json")
    out = _out_dir(args.out)
    md = klippy.MIN_DURATION_S if args.min_duration is None else args.min_duration
    if not md >= 0:
        raise ConfigError(f"--min-duration must be >= 0 s, got {args.min_duration}")
    report = klippy.import_log(args.log, out, min_duration=md)
    report = write_report(args, js, report)
    for s in report["segments"]:
        if s["file"]:
            note = "" if s["excitation"] == "enough" else f" ({s['excitation']})"
            info(args, f"{out / s['file']}: {s['heater']}, {s['duration_s']:g} s, "
                 f"{s['temp_range_C'][0]:g}-{s['temp_range_C'][1]:g} °C{note}")
    return report


def cmd_calibrate(args: argparse.Namespace) -> dict:
    from ..firmware import calibrate

    input_file(args.data, "EST")
    if args.validation:
        input_file(args.validation, "--validation")
    js = output_path(args.json, "--json")
    out = _out_dir(args.out)

    def say(text: str) -> None:
        if not args.quiet:
            print(f"calibrate: {text}", file=sys.stderr)

    kw = {k: getattr(args, k) for k in ("steps", "rollouts", "heater_power")
          if getattr(args, k) is not None}
    command = " ".join(["jthermo calibrate", args.data]
                       + (["--validation", args.validation] if args.validation else [])
                       + ["--out", args.out, "--firmware", args.firmware]
                       + (["--heater", args.heater] if args.heater else [])
                       + ([f"--setpoint {args.setpoint:g}"] if args.setpoint is not None else []))
    report = calibrate.calibrate(args.data, out, validation=args.validation,
                                 firmware=args.firmware, heater=args.heater,
                                 setpoint=args.setpoint, seed=args.seed, progress=say,
                                 oracle=args.oracle,
                                 command=command, **kw)
    report = write_report(args, js, report)
    if not report.get("supported", True):      # said even with --quiet
        print(f"calibrate: not a tuning to use: {report['why_not']}", file=sys.stderr)
    info(args, f"wrote {', '.join(report['files'])}")
    return report
