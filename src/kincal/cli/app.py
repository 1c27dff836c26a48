"""The typer application that every command module registers on."""

from __future__ import annotations

from typing import Annotated

import typer

#: The program's name and one-line help, shared by the whole application and by the
#: one-command application :func:`kincal.cli._one_command` builds for a fast start.
APP_NAME = "kincal"
APP_HELP = ("Kinematic calibration of robot manipulators: robots, kinematics, "
            "measurements, identification, compensation.")

app = typer.Typer(
    name=APP_NAME,
    help=APP_HELP,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _version(value: bool) -> None:
    if value:
        from kincal._version import __version__

        print(f"kincal {__version__}")
        raise typer.Exit()


@app.callback()
def kincal(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True,
                                          help="Print the version and exit.")] = False,
) -> None:
    """Kinematic calibration of robot manipulators: robots, kinematics, measurements,
    identification, compensation. `kincal COMMAND --help` for each command."""
