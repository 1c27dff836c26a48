"""The ``kincal`` command line.

Each command group lives in its own module and registers on
:data:`kincal.cli.app.app`; importing this package registers them all.  User
errors (:class:`kincal.errors.KincalError`) become one line on stderr and exit
code 2, never a traceback.

Layer rule: the top layer; it may import every other layer, and nothing imports it.
"""

from __future__ import annotations

import importlib
import os
import sys

import typer

from kincal.cli.app import APP_HELP, APP_NAME, app, kincal
from kincal.errors import KincalError

#: Command modules in the order their commands appear in ``kincal --help``: the robot
#: and kinematics commands a new user tries first, then the calibration flow.
COMMAND_MODULES = ("kinematics", "motion", "simulate", "calibration", "setupfile",
                   "compensate", "demo", "plan", "export", "fivebar", "filter", "importers",
                   "camera", "board", "fleet")
for _module in COMMAND_MODULES:
    importlib.import_module(f"kincal.cli.{_module}")


def _one_command(argv: list[str]) -> typer.Typer:
    """The application holding only the command ``argv`` names (fast start: typer builds
    the options of that command only); the whole application for anything else."""
    name = argv[0] if argv and not argv[0].startswith("-") else None
    for info in app.registered_commands:
        if info.callback is None:
            continue
        if (info.name or info.callback.__name__.lower().replace("_", "-")) == name:
            single = typer.Typer(name=APP_NAME, help=APP_HELP, no_args_is_help=True,
                                 add_completion=False, pretty_exceptions_enable=False,
                                 rich_markup_mode=None)
            single.callback()(kincal)
            single.registered_commands.append(info)
            return single
    return app


def _run(argv: list[str]) -> int:
    """Run the command line; a usage error (an unknown option, a value out of range) is
    one line too, naming the command whose --help explains it.

    Typer's public API only: calling the application with ``standalone_mode=False``
    returns the command's value and raises what it cannot handle; every command-line
    error of typer's click is a :class:`typer.TyperException` (typer >= 0.27.2)."""
    try:
        rv = _one_command(argv)(args=argv, prog_name="kincal", standalone_mode=False)
    except typer.TyperException as exc:
        ctx = getattr(exc, "ctx", None)
        if type(exc).__name__ == "NoArgsIsHelpError" and ctx is not None:
            print(ctx.get_help())
            return 0
        where = ctx.command_path if ctx is not None else "kincal"
        message = " ".join(exc.format_message().split())
        print(f"error: {message} (see `{where} --help`)", file=sys.stderr)
        return exc.exit_code if exc.exit_code else 2
    except typer.Abort:
        print("error: interrupted", file=sys.stderr)
        return 130
    return rv if isinstance(rv, int) else 0


def main() -> None:
    """Entry point of the ``kincal`` console script: one line on stderr and exit code 2
    for bad input (1 for a result that failed its checks), never a traceback."""
    try:
        code = _run(sys.argv[1:])
    except KincalError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        sys.exit(130)
    except OSError as exc:                      # the system refused: a file, a folder, a disk
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"error: {where}{exc.strerror or exc}", file=sys.stderr)
        sys.exit(2)
    except Exception as exc:                    # a bug: one line, the traceback on request
        if os.environ.get("KINCAL_DEBUG"):
            raise
        print(f"error: internal error in kincal ({type(exc).__name__}: "
              f"{str(exc).splitlines()[0] if str(exc) else 'no message'}); please report it "
              "with the command line (KINCAL_DEBUG=1 shows the traceback)", file=sys.stderr)
        sys.exit(3)
    if code:
        sys.exit(code)
