"""One loader for every kind of robot a command or a notebook may name.

:func:`kincal.robots.files.load_robot` reads serial robots (built-in names, YAML
robot files, URDF files); :func:`kincal.parallel.files.load_fivebar` reads five-bar
parallel robots.  :func:`load_any_robot` looks at the file's ``kind`` and hands it
to the right one, so that ``kincal show fivebar`` and ``kincal show puma560`` work
alike.  It lives above both layers because only here may both be imported.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from kincal.robots.files import load_robot, robot_kind

if TYPE_CHECKING:
    from kincal.parallel.fivebar import FiveBar
    from kincal.robots.chain import Robot

__all__ = ["load_any_robot"]


def load_any_robot(spec: str | os.PathLike[str], base_link: str | None = None,
                   tip_link: str | None = None) -> Robot | FiveBar:
    """A serial :class:`~kincal.robots.chain.Robot` or a :class:`~kincal.parallel.fivebar.FiveBar`.

    Args:
        spec: built-in name (``puma560``, ``fivebar``; see ``kincal robots``), a YAML
            robot file or a URDF file.
        base_link: for URDF files, the chain's first link (None: the URDF's root).
        tip_link: for URDF files, the chain's last link (None: its single leaf).
    """
    if robot_kind(spec) == "fivebar":
        from kincal.parallel.files import load_fivebar  # only for five-bars: fast start

        return load_fivebar(spec)
    robot: Robot = load_robot(spec, base_link=base_link, tip_link=tip_link)
    return robot
