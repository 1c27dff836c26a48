"""One loader for every kind of robot a command or a notebook may name.

:func:`kincal.robots.files.load_serial_robot` reads serial robots (built-in names, YAML
robot files, URDF files); :func:`kincal.parallel.files.load_fivebar` reads five-bar
parallel robots.  :func:`load_any_robot` looks at the file's ``kind`` and hands it
to the right one, so that ``kincal show fivebar`` and ``kincal show puma560`` work
alike.  A calibrated robot's envelope (:mod:`kincal.identify.envelope`) is checked
here: a corrupted section, or one that does not match the robot, is one line.  It
lives above both layers because only here may both be imported.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from kincal.robots.files import load_serial_robot, robot_kind

if TYPE_CHECKING:
    from kincal.parallel.fivebar import FiveBar
    from kincal.robots.chain import Robot

__all__ = ["load_any_robot", "check_envelope"]


def load_any_robot(spec: str | os.PathLike[str], base_link: str | None = None,
                   tip_link: str | None = None) -> Robot | FiveBar:
    """A serial :class:`~kincal.robots.chain.Robot` or a :class:`~kincal.parallel.fivebar.FiveBar`.

    Args:
        spec: built-in name (``puma560``, ``fivebar``; see ``kincal robots``), a YAML
            robot file or a URDF file.
        base_link: for URDF files, the chain's first link (None: the URDF's root).
        tip_link: for URDF files, the chain's last link (None: its single leaf).

    Raises:
        KincalError: the file is bad, or its calibration envelope is corrupted or does
            not match the robot (one line naming the file).
    """
    if robot_kind(spec) == "fivebar":
        from kincal.parallel.files import load_fivebar  # only for five-bars: fast start

        return load_fivebar(spec)
    robot: Robot = load_serial_robot(spec, base_link=base_link, tip_link=tip_link)
    return check_envelope(robot)


def check_envelope(robot: Robot) -> Robot:
    """``robot``, after checking the calibration envelope it carries (if any): a
    corrupted section or one that does not match the robot is one line naming the file."""
    if robot.meta.get("calibration") is not None:
        from kincal.identify.envelope import envelope_of

        envelope_of(robot)
    return robot
