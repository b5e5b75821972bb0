"""`jthermo sweep` and `jthermo demo`: many runs from one command."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import ConfigError
from .common import (
    MAX_ZONES,
    add_common,
    info,
    input_file,
    output_path,
    positive_int,
    progress_bar,
    write_report,
)


def add_parsers(sub) -> None:
    sp = sub.add_parser("sweep", help="grid/random search over orders, controllers, weights")
    sp.add_argument("config", nargs="?", metavar="CONFIG.toml", help="sweep configuration "
                    "(default: the embedded one)")
    sp.add_argument("--ray", metavar="ADDRESS", help="run the trials on a Ray cluster "
                    "('local' starts one here)")
    sp.add_argument("--results", metavar="FILE", help="JSON-lines results file (appended, resumable)")
    sp.add_argument("--summary", action="store_true", help="print the best trials and exit")
    sp.add_argument("--csv", metavar="FILE", help="write every trial as a table (one row per "
                    "trial: parameters, status, metrics; best first)")
    sp.add_argument("--top", type=positive_int(10000), default=10)
    sp.add_argument("--workers", type=positive_int(256), default=None,
                    help="local worker processes (default: 1, in-process)")
    add_common(sp, plot=False)

    sp = sub.add_parser("demo", help="the whole workflow on the virtual printer")
    sp.add_argument("--name", default="demo", help="runs/<name>/report.md")
    sp.add_argument("--quick", action="store_true", help="a shorter run")
    sp.add_argument("--runs-dir", default="runs", metavar="DIR")
    sp.add_argument("--zones", type=positive_int(MAX_ZONES), default=None,
                    help="zones of the virtual printer (default 4)")
    add_common(sp, plot=False)


def cmd_sweep(args: argparse.Namespace) -> dict:
    from .. import sweep

    js = output_path(args.json, "--json")
    table = output_path(args.csv, "--csv")
    if args.config is not None:
        input_file(args.config, "sweep config")
        config = sweep.load_config(args.config)
    else:
        config = sweep.default_config()
    results = Path(args.results) if args.results else sweep.default_results_path(config)
    output_path(str(results), "--results")
    if args.summary:
        rows = sweep.read_results(results)
        best = sweep.best_trials(rows, config, top=args.top)
        print(sweep.format_summary(best, config, total=len(rows)))
        report = {"results": str(results), "n_trials": len(rows), "best": best}
        _write_table(table, rows, config, report)
        return write_report(args, js, report)
    bar = progress_bar(args, f"sweep {config['name']}")
    try:
        report = sweep.run_sweep(config, results, ray_address=args.ray, workers=args.workers,
                                 progress=bar)
    finally:
        bar.close()
    _write_table(table, sweep.read_results(results), config, report)
    report = write_report(args, js, report)
    info(args, f"sweep {config['name']}: {report['n_run']} trials run, {report['n_skipped']} already done, "
               f"{report['n_failed']} failed; results in {results}")
    if report.get("best"):
        info(args, sweep.format_summary(report["best"], config, total=report["n_total"]))
    return report


def _write_table(path: Path | None, rows: list[dict], config: dict, report: dict) -> None:
    """`--csv`: the trials as `sweep.results_frame` lays them out, written atomically."""
    if path is None:
        return
    from .. import sweep
    from .._files import atomic_write_text

    atomic_write_text(path, sweep.results_frame(rows, config).to_csv(index=False))
    report["csv"] = str(path)


def cmd_demo(args: argparse.Namespace) -> dict:
    from .. import demo

    js = output_path(args.json, "--json")
    if not args.name or "/" in args.name or args.name in (".", ".."):
        raise ConfigError(f"--name: expected a plain directory name, got {args.name!r}")
    report = demo.run_demo(name=args.name, quick=args.quick, seed=args.seed,
                           runs_dir=args.runs_dir, quiet=args.quiet, zones=args.zones)
    report = write_report(args, js, report)
    info(args, f"report: {report['report']}")
    return report
