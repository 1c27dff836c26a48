"""Errors meant for people.

Every error a user can cause (a bad file, an unknown robot, an unreachable
target, a rank-deficient request) is raised as a :class:`KincalError` whose
message is one line naming the file, line, column or parameter at fault.  The
CLI prints that line and exits with code 2; library users catch the class.
"""

from __future__ import annotations


class KincalError(Exception):
    """A problem with the user's input, reported as one readable line.

    Args:
        message: what is wrong, naming the file / line / field / parameter.
        source: optional file path or object the message refers to; when given,
            the message is prefixed with ``"{source}: "``.
    """

    exit_code = 2

    def __init__(self, message: str, source: str | None = None) -> None:
        self.source = source
        text = f"{source}: {message}" if source else message
        super().__init__(text.replace("\n", " "))


class RobotFileError(KincalError):
    """A robot description (YAML or URDF) is malformed."""


class MeasurementFileError(KincalError):
    """A measurement file (CSV) is malformed or has ambiguous units."""


class IdentifiabilityError(KincalError):
    """The requested parameters cannot be identified from the data."""


class UnreachableError(KincalError):
    """A target pose cannot be reached."""


class CheckFailedError(KincalError):
    """The work ran, but its result failed a check the user must see (exit status 1).

    E.g. a calibration that did not converge or whose estimates are implausible: the
    command prints its tables and writes what it may (JSON, report), then this one line.
    """

    exit_code = 1
