"""How a robot controller's axis values map to the model's joints.

A robot program stores axis values as the controller shows them (KUKA ``A1 ... A6``,
ABB ``rax_1 ... rax_6``, FANUC ``J1 ... J6``, UR joint lists), in the controller's
units (degrees, or radians for UR).  The model's joints may differ in sign, zero or
coupling: FANUC's ``J3`` is the forearm's angle to the horizontal, not to the upper
arm, so the model's third joint is a sum of ``J2`` and ``J3``.  A robot file states
the map in an optional ``controller`` section::

    controller:
      vendor: fanuc                 # kuka | abb | fanuc | ur
      axes: [J1, J2, J3, J4, J5, J6]
      unit: deg                     # unit of the axis values in programs: deg | rad
      joints:                       # model joint = sum of coefficient x axis (default:
        q3: {J2: -1, J3: -1}        #   model joint k = axis k)
        q4: {J4: -1}
      offsets: {q2: 0}              # added after the sum, in ``unit``

so that ``q = M a + b`` with ``a`` the axis values in SI units (rad / m).  Without the
section a robot's axes are its joints, in degrees (rad for UR).

Units: the map works in SI (rad, m); :meth:`ControllerMap.to_model` and
:meth:`~ControllerMap.to_axes` convert from and to the controller's unit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import RobotFileError
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["VENDORS", "ControllerMap", "controller_map"]

#: Controller families whose programs kincal reads.
VENDORS = ("kuka", "abb", "fanuc", "ur")
_UNITS = {"deg": math.pi / 180.0, "rad": 1.0}


@dataclass(frozen=True)
class ControllerMap:
    """``q = matrix @ a + offset``: model joints from controller axis values (SI).

    Attributes:
        vendor: one of :data:`VENDORS`, or ``""`` when unknown.
        axes: the controller's axis names, in the order programs list them.
        unit: ``"deg"`` or ``"rad"``: the unit of revolute axis values in programs.
        matrix: (n, n) coefficients; invertible.
        offset: (n,) [rad / m].
    """

    vendor: str
    axes: tuple[str, ...]
    unit: str
    matrix: Array
    offset: Array

    @property
    def scale(self) -> float:
        """Factor from the program's unit to rad."""
        return _UNITS[self.unit]

    def to_model(self, axes: ArrayLike) -> Array:
        """Model joints [rad] from controller axis values in the controller's unit, (..., n)."""
        a = np.asarray(axes, dtype=float) * self.scale
        return a @ self.matrix.T + self.offset

    def to_axes(self, q: ArrayLike) -> Array:
        """Controller axis values (its unit) from model joints [rad], (..., n)."""
        qq = np.asarray(q, dtype=float) - self.offset
        a = (np.linalg.solve(self.matrix, qq.T).T if qq.ndim > 1
             else np.linalg.solve(self.matrix, qq))
        return np.asarray(a / self.scale, dtype=np.float64)

    @property
    def is_identity(self) -> bool:
        """True when the axes are the model joints (up to the unit)."""
        return bool(np.array_equal(self.matrix, np.eye(len(self.axes)))
                    and not np.any(self.offset))


def _fail(source: str, field: str, what: str) -> RobotFileError:
    return RobotFileError(f"field 'controller.{field}' {what}", source=source)


def controller_map(robot: Robot, vendor: str | None = None) -> ControllerMap:
    """The robot's :class:`ControllerMap` (from ``robot.meta["controller"]``).

    Without a ``controller`` section the axes are the model joints, named after them,
    in degrees (radians when ``vendor == "ur"``).
    """
    spec = robot.meta.get("controller")
    n = robot.n
    source = str(robot.meta.get("source_file", robot.name))
    if not isinstance(spec, Mapping):
        unit = "rad" if vendor == "ur" else "deg"
        return ControllerMap(vendor or "", tuple(robot.joint_names), unit, np.eye(n),
                             np.zeros(n))
    v = str(spec.get("vendor", vendor or ""))
    if v and v not in VENDORS:
        raise _fail(source, "vendor", f"must be one of {', '.join(VENDORS)}, got {v!r}")
    axes = spec.get("axes", list(robot.joint_names))
    if not isinstance(axes, list) or len(axes) != n:
        raise _fail(source, "axes", f"must list {n} axis names")
    axes = tuple(str(a) for a in axes)
    unit = str(spec.get("unit", "rad" if v == "ur" else "deg"))
    if unit not in _UNITS:
        raise _fail(source, "unit", f"must be deg or rad, got {unit!r}")
    M = np.eye(n)
    joints = spec.get("joints") or {}
    if not isinstance(joints, Mapping):
        raise _fail(source, "joints", "must map model joints to {axis: coefficient}")
    for jname, combo in joints.items():
        if str(jname) not in robot.joint_names:
            raise _fail(source, f"joints.{jname}", "names no joint of the robot")
        if not isinstance(combo, Mapping):
            raise _fail(source, f"joints.{jname}", "must map axes to coefficients")
        row = np.zeros(n)
        for ax, coef in combo.items():
            if str(ax) not in axes:
                raise _fail(source, f"joints.{jname}.{ax}", "names no axis in 'axes'")
            row[axes.index(str(ax))] = _number(coef, source, f"joints.{jname}.{ax}")
        M[robot.joint_names.index(str(jname))] = row
    if abs(np.linalg.det(M)) < 1e-12:
        raise _fail(source, "joints", "is not invertible (two joints use the same axes)")
    b = np.zeros(n)
    offsets = spec.get("offsets") or {}
    if not isinstance(offsets, Mapping):
        raise _fail(source, "offsets", "must map model joints to values")
    for jname, val in offsets.items():
        if str(jname) not in robot.joint_names:
            raise _fail(source, f"offsets.{jname}", "names no joint of the robot")
        b[robot.joint_names.index(str(jname))] = _number(val, source, f"offsets.{jname}") \
            * _UNITS[unit]
    return ControllerMap(v, axes, unit, M, b)


def _number(value: Any, source: str, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(source, field, f"must be a number, got {value!r}")
    return float(value)
