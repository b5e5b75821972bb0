"""The `jthermo` command: parse, check inputs up front, call the library, report.

Every command takes `--json PATH` (a JSON report written atomically, with the wall time
`seconds` split into `compile_s` and `run_s`), `--seed`, `--quiet`, `--verbose` and `--no-cache`:
compiled code is kept in a persistent cache between runs (`jthermo.runtime`).
Errors are one line on stderr and exit status 2, never a traceback and never a partial
output file; Ctrl-C prints one line and exits with 130, leaving saved files intact. A command
that makes no progress for `--timeout S` seconds (default 1200, before or after the command's
name; 0: never) says so with the stage it is in and exits with 2 (`watchdog`).
Imports of the library are lazy (inside each command), so `jthermo --help` is fast.

    jthermo fit EST.csv --model {arx,armax,oe,bj,ss,greybox} [--orders ...] [--validation VAL.csv]
                [--common-denominator] [--rest-level T[,T...]] [--out MODEL] [--json REPORT.json]
                [--seed S] [--plot DIR]
    jthermo validate MODEL DATA.csv [--json R.json] [--plot DIR]
    jthermo simulate --scenario {tracking,powder,print,preheat,ensemble} --controller C
                [--controller-file CTRL] [--plant printer|MODEL] [--zones N] [--rollouts B]
                [--duration SECONDS] [--seed S] [--json OUT] [--plot DIR]
    jthermo generate --experiment prbs --zones N --duration SECONDS [--effects ...] --out DATA.csv
    jthermo tune --controller C [--model MODEL] [--plant printer] [--rollouts B] [--steps K]
                [--seed S] [--json OUT] [--out CTRL] [--plot DIR]
    jthermo diagnose EST.csv --validation VAL.csv --json OUT.json [--model greybox] [--seed S]
                [--report DIR]
    jthermo sweep [CONFIG.toml] [--ray ADDRESS] [--results FILE] [--summary] [--workers N]
    jthermo demo [--name NAME] [--quick]
    jthermo export CTRL --to {c,json} --out DIR [--name NAME] [--json REPORT.json]
    jthermo import klippy.log --out DIR [--json REPORT.json]
    jthermo calibrate EST.csv [--validation VAL.csv] --out DIR [--firmware klipper|marlin|kalico|c]
                [--heater NAME] [--setpoint C] [--json REPORT.json]

The commands live by family: `identify` (fit, validate), `control` (simulate, generate, tune),
`diagnose`, `batch` (sweep, demo); `common` holds the argument types and input/output checks,
`printer_model` the virtual printer's design model that `simulate` designs on.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

from ..errors import JThermoError
from . import batch, control, diagnose, export, firmware, identify
from .common import Parser, UsageError, add_timeout, exit_now

EXIT_OK = 0
EXIT_ERROR = 2
EXIT_INTERRUPT = 130

COMMANDS = {"fit": identify.cmd_fit, "validate": identify.cmd_validate,
            "simulate": control.cmd_simulate, "generate": control.cmd_generate,
            "tune": control.cmd_tune, "diagnose": diagnose.cmd_diagnose,
            "sweep": batch.cmd_sweep, "demo": batch.cmd_demo, "export": export.cmd_export,
            "import": firmware.cmd_import, "calibrate": firmware.cmd_calibrate}


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="jthermo", description="Identify thermal models of multi-zone heated systems "
               "and tune their controllers (JAX).")
    from .. import __version__

    p.add_argument("--version", action="version", version=f"jthermo {__version__}")
    add_timeout(p, default=None)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for family in (identify, control, diagnose, batch, export, firmware):
        family.add_parsers(sub)
    return p


# ---------------------------------------------------------------- entry point


def _one_line(text: str, limit: int = 400) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


def _fail(message: str) -> int:
    print(_one_line(f"jthermo: error: {message}"), file=sys.stderr)
    return EXIT_ERROR


#: BLAS / OpenMP thread variables: the command sets all to 1 when the user set none
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> bool:
    """One BLAS thread for the command, unless the user set a thread variable or NumPy is
    already loaded (an in-process caller: too late to matter). OpenBLAS's spinning worker
    threads made `jthermo fit` several times slower in wall and CPU time on a busy 2-core
    machine. Returns whether it set them."""
    if "numpy" in sys.modules or any(v in os.environ for v in BLAS_THREAD_VARS):
        return False
    for v in BLAS_THREAD_VARS:
        os.environ[v] = "1"
    return True


def main(argv: list[str] | None = None) -> int:
    """Run the `jthermo` command with `argv` (default `sys.argv[1:]`); returns the exit status."""
    one_blas_thread()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except UsageError as exc:
        return _fail(str(exc))
    except SystemExit as exc:  # --help / --version
        return int(exc.code or 0) if not isinstance(exc.code, str) else _fail(exc.code)
    if args.command is None:
        parser.print_help(sys.stderr)
        return EXIT_ERROR
    debug = bool(os.environ.get("JTHERMO_DEBUG"))
    from .. import progress
    from .watchdog import DEFAULT_LIMIT_S, Watchdog, listen_to_compiles

    limit = DEFAULT_LIMIT_S if args.timeout is None else args.timeout
    dog = Watchdog(limit, f"jthermo {args.command}").start()
    try:
        with warnings.catch_warnings(), progress.stage(args.command):
            if not debug:
                warnings.simplefilter("ignore")
            from .. import runtime

            args.stopwatch = runtime.Stopwatch()
            if getattr(args, "no_cache", False):
                runtime.disable_cache("--no-cache")
            else:
                runtime.enable_cache()
            runtime.unroll_threefry()   # the same random bits, fewer CPU seconds
            runtime.one_matrix_at_a_time()   # no LAPACK kernel waits on XLA's pool
            if getattr(args, "verbose", False):
                print(f"jthermo: {runtime.cache_info()}", file=sys.stderr)
            import jax

            jax.config.update("jax_enable_x64", True)
            listen_to_compiles()   # a compile is progress: the watchdog hears of each
            if args.quiet:
                from ..progress import set_quiet

                set_quiet(True)
            COMMANDS[args.command](args)
    except KeyboardInterrupt:
        print("jthermo: interrupted (saved files are intact)", file=sys.stderr)
        return EXIT_INTERRUPT
    except BaseException as exc:  # the contract: one line, status 2
        if isinstance(exc, SystemExit):
            return int(exc.code) if isinstance(exc.code, int) else EXIT_ERROR
        if debug:
            raise
        if isinstance(exc, JThermoError):
            return _fail(str(exc))
        if isinstance(exc, MemoryError):
            return _fail("out of memory (try fewer rollouts, zones or a shorter duration)")
        if isinstance(exc, OSError) and exc.filename is not None:
            return _fail(f"{exc.filename}: {exc.strerror}")
        return _fail(f"internal error ({type(exc).__name__}): {exc}")
    finally:
        dog.stop()
        if args.command is not None and getattr(args, "quiet", False):
            from ..progress import set_quiet

            set_quiet(False)
    return EXIT_OK


def entry() -> None:  # pragma: no cover - console script wrapper
    exit_now(main())   # no interpreter teardown (`common.exit_now`)
