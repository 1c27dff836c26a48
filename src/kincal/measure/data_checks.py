"""Joint data the robot cannot have produced: readings beyond the joint limits, and
revolute columns whose values only make sense in the other angle unit.

Both checks run on the joint readings *as read* (SI: rad for revolute joints, m for
prismatic ones), before any fit, and name the file, the line and the joint:

* **Beyond the limits.**  A reading ``q_j`` with ``q_j < lower_j - slack_j`` or
  ``q_j > upper_j + slack_j``, ``slack_j = max(LIMIT_SLACK, LIMIT_SHARE (upper_j -
  lower_j))``: 1 % of the joint's range, at least 1e-3 rad (0.057 deg) or 1e-4 m.  A
  controller's soft limits let a joint overshoot a little and robot files round their
  limits (the TIAGo's torso reads 350.2 mm against its 350 mm limit); a reading in
  another unit, in another joint's column or of another robot is off by far more (and a
  robot file whose limits are wrong is worth knowing about).  A joint without limits
  (infinite) is not checked, nor a robot without any.
* **The other angle unit** (revolute joints only; a file's joint columns are read in
  one unit each, ``q2_rad`` or ``q2_deg``):

  - *degrees read as radians*: a column read in a radian unit whose values span more
    than ``max(2 pi, upper - lower) * 1.05`` (one turn, or the joint's range when that is
    wider) while every value lies within +-360 (the span of degree readings).  A revolute
    joint cannot move over more than its range; degree values of any real motion (tens of
    degrees) do.
  - *radians read as degrees*: *every* revolute column of the file read in a degree
    unit stays within +-2 pi (+-6.283 "degrees": radian readings of joints with limits
    up to one turn either way), the file moves some joint at all (a spread above 0.01
    deg, so one repeated pose is not flagged) and the robot's joints could move far more
    (at least one revolute range wider than 30 deg).  A calibration moves its joints over
    tens of degrees: an arm that stayed within +-6.3 deg on every axis is a file of
    radians under ``_deg`` headers.

  Columns read in other angle units (``mrad``, ``arcsec`` ...) are not judged; a column
  without a known unit (blocks built in memory) is judged as radians.  A continuous
  joint (no limits) whose readings wind over more than one turn, all within +-360, would
  be taken for degrees: calibration chains have none.

:func:`joint_data_problems` returns one sentence per problem (first offending row of
each joint); :func:`joint_data_line` joins them into the one line a command prints.
Callers decide what a problem means: ``calibrate`` refuses the calibration (exit 1, no
robot written unless ``--force``), ``validate`` refuses before it computes (exit 1, one
line), ``fk`` / ``jacobian`` print the answer and then exit 1 with the line.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kincal.errors import CheckFailedError
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["LIMIT_SLACK", "LIMIT_SHARE", "JointProblem", "limit_problems", "unit_problems",
           "joint_data_problems", "joint_data_line", "block_joint_problems",
           "command_line_joints", "refuse_joint_data"]

#: Readings this far beyond a limit are always accepted [rad for revolute, m for prismatic].
LIMIT_SLACK = {"revolute": 1e-3, "prismatic": 1e-4}

#: ... and this share of the joint's range (module docstring).
LIMIT_SHARE = 0.01

#: Unit names read as radians / degrees by the angle-unit rule (others are not judged).
_RADIAN_UNITS = ("rad",)
_DEGREE_UNITS = ("deg",)


@dataclass(frozen=True)
class JointProblem:
    """One problem with a file's joint readings.

    Attributes:
        source: the file (or the block's name when it was not read from a file).
        kind: ``"limits"`` or ``"unit"``.
        words: the sentence, without the source (``"line 7: q2 = 300 deg is beyond ..."``).
        joints: the joints it is about.
    """

    source: str
    kind: str
    words: str
    joints: tuple[str, ...] = ()

    def line(self) -> str:
        return f"{self.source}: {self.words}"


def _show(value: float, kind: str) -> str:
    return f"{math.degrees(value):.4g} deg" if kind == "revolute" else f"{value * 1e3:.4g} mm"


def _where(lines: Sequence[int] | None, row: int, rows: int) -> str:
    if lines is not None:
        return f"line {int(lines[row])}: "
    return f"row {row + 1}: " if rows > 1 else ""


def limit_problems(robot: Robot, q: Array, source: str,
                   lines: Sequence[int] | None = None) -> list[JointProblem]:
    """Readings beyond the joint limits (module docstring), one per joint: its first
    offending row, and how many rows are beyond.

    Args:
        robot: the robot (its ``joints``: ``lower``, ``upper`` [rad / m], ``kind``).
        q: (N, n) joint readings [rad / m].
        source: the file (for the sentence).
        lines: (N,) file line of every row (None: 1-based row numbers).
    """
    q = np.asarray(q, dtype=float)
    out: list[JointProblem] = []
    if q.ndim != 2 or q.shape[1] != robot.n or q.shape[0] == 0:
        return out
    for j, joint in enumerate(robot.joints):
        lo, hi = float(joint.lower), float(joint.upper)
        if not (math.isfinite(lo) or math.isfinite(hi)):
            continue
        width = hi - lo if math.isfinite(hi - lo) else 0.0
        slack = max(LIMIT_SLACK.get(joint.kind, 0.0), LIMIT_SHARE * width)
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero((q[:, j] < lo - slack) | (q[:, j] > hi + slack))
        if bad.size == 0:
            continue
        i = int(bad[0])
        more = f" ({bad.size} of {q.shape[0]} rows beyond)" if bad.size > 1 else ""
        lim = (f"[{_show(lo, joint.kind) if math.isfinite(lo) else '-inf'}, "
               f"{_show(hi, joint.kind) if math.isfinite(hi) else 'inf'}]")
        out.append(JointProblem(source, "limits",
                                f"{_where(lines, i, q.shape[0])}joint {joint.name} = "
                                f"{_show(float(q[i, j]), joint.kind)} is beyond its limits "
                                f"{lim}{more}", (joint.name,)))
    return out


def _unit_family(unit: str | None) -> str | None:
    if unit in _RADIAN_UNITS:
        return "rad"
    if unit in _DEGREE_UNITS:
        return "deg"
    return None


def unit_problems(robot: Robot, q: Array, source: str,
                  units: Sequence[str | None]) -> list[JointProblem]:
    """Revolute columns whose values only make sense in the other angle unit (module
    docstring).

    Args:
        robot: the robot (joint kinds and limits).
        q: (N, n) joint readings as read [rad / m].
        source: the file.
        units: per joint, the unit its column was read in (``"rad"``, ``"deg"`` ...;
            None when unknown: judged as radians).
    """
    q = np.asarray(q, dtype=float)
    out: list[JointProblem] = []
    if q.ndim != 2 or q.shape[1] != robot.n or q.shape[0] == 0:
        return out
    fam = [_unit_family(u) if u is not None else "rad" for u in units]
    rev = [j for j, joint in enumerate(robot.joints) if joint.kind == "revolute"]
    wide: list[tuple[int, float]] = []
    for j in rev:
        joint = robot.joints[j]
        if fam[j] != "rad":
            continue
        col = q[:, j]
        span = float(np.max(col) - np.min(col))
        width = float(joint.upper - joint.lower)
        allowed = max(2 * math.pi, width if math.isfinite(width) else 0.0) * 1.05
        if span > allowed and float(np.max(np.abs(col))) <= 360.0 * 1.001:
            wide.append((j, span))
    if wide:
        names = [robot.joints[j].name for j, _ in wide]
        j, span = max(wide, key=lambda x: x[1])
        cols = ", ".join(names[:4]) + (" ..." if len(names) > 4 else "")
        out.append(JointProblem(
            source, "unit",
            f"joint column{'s' if len(names) > 1 else ''} {cols} (read in "
            f"{units[wide[0][0]] or 'rad'}): values spanning up to {span:.4g} "
            f"({robot.joints[j].name}), more than one turn (6.283 rad) of a revolute joint: "
            f"they look like degrees (write {names[0]}_deg ..., or give --units)",
            tuple(names)))
    deg = [j for j in rev if fam[j] == "deg"]
    if deg and len(deg) == len(rev):
        small = all(float(np.max(np.abs(q[:, j]))) <= math.radians(2 * math.pi) * 1.0001
                    for j in deg)
        moved = max(float(np.ptp(q[:, j])) for j in deg) > math.radians(0.01)
        widths = [float(robot.joints[j].upper - robot.joints[j].lower) for j in deg]
        could = any(not math.isfinite(w) or w > math.radians(30) for w in widths)
        if small and moved and could:
            shown = ", ".join(robot.joints[j].name for j in deg[:3])
            out.append(JointProblem(
                source, "unit",
                f"every revolute joint column ({shown}{' ...' if len(deg) > 3 else ''}, "
                f"read in deg) stays within +-6.283 deg: the values look like radians "
                f"(write the columns as _rad, or give --units)",
                tuple(robot.joints[j].name for j in deg)))
    return out


def joint_data_problems(robot: Robot, q: Array, source: str,
                        lines: Sequence[int] | None = None,
                        units: Sequence[str | None] | None = None) -> list[JointProblem]:
    """Angle-unit problems first (they explain the limit problems that follow), then
    readings beyond the limits.  ``units=None``: every column read in rad / m."""
    u = list(units) if units is not None else [None] * robot.n
    found = unit_problems(robot, q, source, u)
    explained = {j for p in found for j in p.joints}
    return found + [p for p in limit_problems(robot, q, source, lines)
                    if not explained.intersection(p.joints)]


def block_joint_problems(robot: Robot, blocks: Sequence[object]) -> list[JointProblem]:
    """:func:`joint_data_problems` of measurement blocks: each file once (its table's
    readings, line numbers and units when the block was read from a file; else the
    block's ``q`` under its name, read as SI)."""
    out: list[JointProblem] = []
    seen: set[str] = set()
    for b in blocks:
        prov = getattr(b, "provenance", None)
        table = getattr(prov, "table", None)
        source = str(getattr(prov, "path", None) or getattr(b, "name", "data"))
        if source in seen:
            continue
        seen.add(source)
        if table is not None and np.ndim(table.q) == 2 and table.q.shape[1] == robot.n:
            units = [table.units.get(j.name) for j in robot.joints]
            out += joint_data_problems(robot, table.q, source, list(table.lines), units)
            continue
        q = getattr(b, "q", None)
        if q is not None:
            out += joint_data_problems(robot, np.asarray(q, dtype=float), source)
    return out


def command_line_joints(robot: Robot, q: Array, option: str = "--q", deg: bool = False
                        ) -> str:
    """The one line for joint values given on the command line beyond the limits
    (``""`` when they are inside): ``option --q: joint q2 = 1146 deg is beyond its limits
    [-45 deg, 225 deg] (numbers without a unit are read as radians: --deg reads
    degrees)``."""
    found = limit_problems(robot, np.atleast_2d(np.asarray(q, dtype=float)), f"option {option}")
    if not found:
        return ""
    hint = "" if deg else (" (numbers without a unit are read as radians: --deg reads "
                           "degrees)")
    return joint_data_line(found) + hint


def refuse_joint_data(robot: Robot, blocks: Sequence[object]) -> None:
    """Raise :class:`~kincal.errors.CheckFailedError` (exit 1) with the one line of
    :func:`block_joint_problems` when the blocks' joint data have a problem."""
    line = joint_data_line(block_joint_problems(robot, blocks))
    if line:
        raise CheckFailedError(f"joint data this robot cannot have produced: {line}")


def joint_data_line(problems: Sequence[JointProblem], limit: int = 2) -> str:
    """One line: the first ``limit`` problems (each source named once), and how many more."""
    if not problems:
        return ""
    parts: list[str] = []
    last = None
    for p in problems[:limit]:
        parts.append(p.words if p.source == last else p.line())
        last = p.source
    more = len(problems) - limit
    return "; ".join(parts) + (f"; and {more} more" if more > 0 else "")
