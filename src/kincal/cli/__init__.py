"""The ``kincal`` command line.

Each command group lives in its own module and registers on
:data:`kincal.cli.app.app`; importing this package registers them all.  User
errors (:class:`kincal.errors.KincalError`) become one line on stderr and exit
code 2, never a traceback.
"""

from __future__ import annotations

import sys

from kincal.cli import (  # noqa: F401  (imported to register their commands)
    calibration,
    compensate,
    demo,
    export,
    fivebar,
    kinematics,
    motion,
    plan,
    simulate,
)
from kincal.cli.app import app
from kincal.errors import KincalError


def main() -> None:
    """Entry point of the ``kincal`` console script."""
    try:
        app()
    except KincalError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
