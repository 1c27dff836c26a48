"""The ``kincal`` command line.

Each command group lives in its own module and registers on
:data:`kincal.cli.app.app`; importing this package registers them all.  User
errors (:class:`kincal.errors.KincalError`) become one line on stderr and exit
code 2, never a traceback.

Layer rule: the top layer; it may import every other layer, and nothing imports it.
"""

from __future__ import annotations

import importlib
import sys

from kincal.cli.app import app
from kincal.errors import KincalError

#: Command modules in the order their commands appear in ``kincal --help``: the robot
#: and kinematics commands a new user tries first, then the calibration flow.
COMMAND_MODULES = ("kinematics", "motion", "simulate", "calibration", "compensate", "demo",
                   "plan", "export", "fivebar", "filter", "importers", "fleet")
for _module in COMMAND_MODULES:
    importlib.import_module(f"kincal.cli.{_module}")


def main() -> None:
    """Entry point of the ``kincal`` console script."""
    try:
        app()
    except KincalError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
