"""`jthermo export`: a saved controller as code a printer runs (C) or as coefficient tables."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import ConfigError
from .common import add_common, info, input_file, output_path, write_report


def add_parsers(sub) -> None:
    sp = sub.add_parser("export", help="a saved controller as C code or JSON coefficient tables")
    sp.add_argument("controller", metavar="CTRL", help="a controller saved by `jthermo tune --out`")
    sp.add_argument("--to", required=True, choices=("c", "json"), help="C header + source, or JSON tables")
    sp.add_argument("--out", required=True, metavar="DIR", help="directory to write into")
    sp.add_argument("--name", default="jthermo_ctrl", help="C identifier / file stem (default jthermo_ctrl)")
    add_common(sp, plot=False)


def cmd_export(args: argparse.Namespace) -> dict:
    from .. import io
    from ..control import export

    input_file(args.controller, "CTRL")
    js = output_path(args.json, "--json")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out}: exists and is not a directory")
    ctrl = io.load_controller(args.controller)
    t = export.tables(ctrl)      # refuses what it cannot export before anything is written
    if args.to == "c":
        files = [str(p) for p in export.to_c(ctrl, out, name=args.name)]
    else:
        out.mkdir(parents=True, exist_ok=True)
        files = [str(export.to_json(ctrl, out / f"{args.name}.json"))]
    report = {"controller": str(args.controller), "type": type(ctrl).__name__, "kind": t["kind"],
              "schedule_feedforward": "feedforward" in t, "to": args.to, "files": files,
              "ts": t["ts"], "inputs": t["n"]}
    report = write_report(args, js, report)
    info(args, f"exported {report['type']} ({t['kind']}) to " + ", ".join(files))
    return report
