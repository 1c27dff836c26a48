"""The typer application that every command module registers on."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="kincal",
    help="Kinematic calibration of robot manipulators: robots, kinematics, "
    "measurements, identification, compensation.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
