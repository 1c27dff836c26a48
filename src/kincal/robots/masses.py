"""Link masses stated in a robot file (the ``masses:`` section), for gravity compliance.

A vendor states each link's mass and centre of mass in that link's own frame; Universal
Robots' table ("Parameters for calculations of kinematics and dynamics", universal-robots.com,
article 45257) gives them in the link's standard-DH frame ``i``, the frame at the end of
DH row ``i``.  A robot file holds them as written there::

    masses:
      frame: dh            # centres of mass in each link's standard-DH frame
      source: Universal Robots, "Parameters for calculations of kinematics and dynamics"
      links:
        - {joint: shoulder_pan, mass: 7.1, com: [0.021, 0.0, 0.027]}    # kg, m
        ...

:func:`stated_masses` turns them into :class:`~kincal.robots.gravity.PointMass` rows,
whose centre of mass is in the frame just after the joint's rotation ``Rz(theta + q)``:
DH row ``i`` is ``Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``, so a point ``c`` of
frame ``i`` sits at

    c' = Tz(d) Tx(a) Rx(alpha) c = (a + c_x, c_y cos(alpha) - c_z sin(alpha),
                                    d + c_y sin(alpha) + c_z cos(alpha))        [m]

in that frame, with the row's nominal ``a, d, alpha`` (the masses do not move with a
calibration's few tenths of a millimetre).  ``frame: joint`` gives them in that frame
directly.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from kincal.errors import RobotFileError
from kincal.robots.chain import Robot
from kincal.robots.gravity import PointMass

__all__ = ["stated_masses", "MASS_FRAMES"]

#: Frames a ``masses:`` section may state its centres of mass in.
MASS_FRAMES = ("dh", "joint")


def _fail(robot: Robot, what: str) -> RobotFileError:
    where = str(robot.meta.get("file", robot.name))
    return RobotFileError(f"robot {where}: masses{what}")


def stated_masses(robot: Robot) -> list[PointMass] | None:
    """The robot file's ``masses:`` as point masses on its joints, or None without one.

    One-line :class:`~kincal.errors.RobotFileError` for a row naming no joint of the
    robot, a mass that is negative or not finite, a centre of mass that is not three
    numbers, or ``frame: dh`` on a robot that is not in standard DH."""
    sec = robot.meta.get("masses")
    if sec is None:
        return None
    if not isinstance(sec, Mapping) or not isinstance(sec.get("links"), list | tuple):
        raise _fail(robot, ": needs 'frame' and a list 'links' of {joint, mass, com}")
    frame = str(sec.get("frame", "dh"))
    if frame not in MASS_FRAMES:
        raise _fail(robot, f".frame {frame!r} is not one of {', '.join(MASS_FRAMES)}")
    if frame == "dh" and robot.meta.get("convention") != "standard_dh":
        raise _fail(robot, ".frame dh needs a standard-DH robot (convention standard_dh); "
                    "give frame: joint")
    names = [j.name for j in robot.joints]
    values = robot.params()
    out: list[PointMass] = []
    for i, row in enumerate(sec["links"]):
        if not isinstance(row, Mapping) or str(row.get("joint")) not in names:
            raise _fail(robot, f".links[{i}]: 'joint' must name a joint of the robot "
                        f"({', '.join(names)})")
        j = names.index(str(row["joint"]))
        try:
            mass = float(row["mass"])
            c = np.asarray(row["com"], dtype=float)
        except (KeyError, TypeError, ValueError):
            raise _fail(robot, f".links[{i}]: needs mass [kg] and com [x, y, z] [m]") from None
        if not (np.isfinite(mass) and mass >= 0) or c.shape != (3,) or \
                not np.all(np.isfinite(c)):
            raise _fail(robot, f".links[{i}]: mass must be >= 0 and com three finite numbers")
        if frame == "dh":
            k = j + 1
            a, d, al = values[f"a[{k}]"], values[f"d[{k}]"], values[f"alpha[{k}]"]
            c = np.array([a + c[0], c[1] * np.cos(al) - c[2] * np.sin(al),
                          d + c[1] * np.sin(al) + c[2] * np.cos(al)])
        out.append(PointMass(j, mass, (float(c[0]), float(c[1]), float(c[2])), names[j]))
    return out

