"""How a robot controller's axis values map to the model's joints: the joint map.

A robot program stores axis values as the controller shows them (KUKA ``A1 ... A6``,
ABB ``rax_1 ... rax_6``, FANUC ``J1 ... J6``, UR joint lists, a servo's encoder counts), in
the controller's units (degrees, radians for UR, counts for hobby servos).  The model's
joints may differ in sign, zero, gear ratio or coupling: FANUC's ``J3`` is the forearm's
angle to the horizontal, not to the upper arm, so the model's third joint is a sum of
``J2`` and ``J3``.  A robot file states the map in an optional ``controller`` section
(``joint_map`` is another name for it)::

    controller:
      vendor: fanuc                 # kuka | abb | fanuc | ur (programs kincal reads), or none
      axes: [J1, J2, J3, J4, J5, J6]
      unit: deg                     # unit of the axis values: deg | rad | counts
      counts_per_turn: 4096         # with unit: counts (encoder counts per axis turn)
      joints:                       # model joint = sum of coefficient x axis (default:
        q3: {J2: -1, J3: -1}        #   model joint k = axis k); a coefficient is the sign
        q4: {J4: -1}                #   and gear ratio (0.5: the joint turns half the axis)
      offsets: {q2: 0}              # added after the sum, in ``unit``: the model's value
                                    #   at axis value 0 (a servo's centre: -2048 counts)

so that ``q = M a + b`` with ``a`` the axis values in SI units (rad / m).  Without the
section a robot's axes are its joints, in degrees (rad for UR).

A calibration that moves a joint's zero (its offset parameter) moves the controller's zero:
:func:`axis_zero_shifts` says it per axis, in the controller's units (``J3 zero: +0.120
deg``): the calibrated arm at axis values ``a`` is where the nominal model is at
``a + shift``.

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

__all__ = ["VENDORS", "ControllerMap", "ZeroShift", "axis_zero_shifts",
           "calibration_zero_shifts", "controller_map", "joint_zero_shifts"]

#: Controller families whose programs kincal reads.
VENDORS = ("kuka", "abb", "fanuc", "ur")
_UNITS = {"deg": math.pi / 180.0, "rad": 1.0, "counts": 0.0}    # counts: see ControllerMap.scale


@dataclass(frozen=True)
class ControllerMap:
    """``q = matrix @ a + offset``: model joints from controller axis values (SI).

    Attributes:
        vendor: one of :data:`VENDORS`, or ``""`` when unknown.
        axes: the controller's axis names, in the order programs list them.
        unit: ``"deg"``, ``"rad"`` or ``"counts"``: the unit of revolute axis values.
        matrix: (n, n) coefficients; invertible.
        offset: (n,) [rad / m].
        counts_per_turn: encoder counts per axis turn (``unit == "counts"`` only).
    """

    vendor: str
    axes: tuple[str, ...]
    unit: str
    matrix: Array
    offset: Array
    counts_per_turn: float = 0.0

    @property
    def scale(self) -> float:
        """Factor from the program's unit to rad (``2 pi / counts_per_turn`` for counts)."""
        if self.unit == "counts":
            return 2.0 * math.pi / self.counts_per_turn
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
        raise _fail(source, "unit", f"must be deg, rad or counts, got {unit!r}")
    cpt = 0.0
    if unit == "counts":
        cpt = _number(spec.get("counts_per_turn"), source, "counts_per_turn")
        if not cpt > 0 or not math.isfinite(cpt):
            raise _fail(source, "counts_per_turn", f"must be a positive number, got {cpt!r}")
    elif "counts_per_turn" in spec:
        raise _fail(source, "counts_per_turn", "is only allowed with unit: counts")
    scale = 2.0 * math.pi / cpt if unit == "counts" else _UNITS[unit]
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
    if not np.all(np.isfinite(M)):
        raise _fail(source, "joints", "has a coefficient that is not finite")
    b = np.zeros(n)
    offsets = spec.get("offsets") or {}
    if not isinstance(offsets, Mapping):
        raise _fail(source, "offsets", "must map model joints to values")
    for jname, val in offsets.items():
        if str(jname) not in robot.joint_names:
            raise _fail(source, f"offsets.{jname}", "names no joint of the robot")
        b[robot.joint_names.index(str(jname))] = _number(val, source, f"offsets.{jname}") \
            * scale
    return ControllerMap(v, axes, unit, M, b, cpt)


def _number(value: Any, source: str, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(source, field, f"must be a number, got {value!r}")
    return float(value)


def joint_zero_shifts(nominal: Robot, calibrated: Robot) -> Array:
    """How far each model joint's zero moved between ``nominal`` and ``calibrated`` (n,).

    The joint variable enters its elementary transform as ``p + s q`` (``p`` the offset
    parameter, ``s = +-1`` the axis direction), so a change ``dp`` of the offset equals a
    change ``dq = dp / s`` of the joint: ``calibrated.fk(q) == nominal.fk(q + dq)`` when
    only offsets changed.  Joints whose transform has no offset parameter get 0.
    Units: rad (revolute), m (prismatic).
    """
    out = np.zeros(nominal.n)
    nom = nominal.params()
    cal = calibrated.params()
    for et in nominal.ets:
        if et.joint < 0 or et.param < 0:
            continue
        name = nominal.param_names[et.param]
        if name in cal:
            out[et.joint] = (cal[name] - nom[name]) / et.scale
    return out


@dataclass(frozen=True)
class ZeroShift:
    """One controller axis whose zero a calibration moved.

    Attributes:
        axis: the controller's axis name (``J3``).
        shift: the change in the controller's unit: the calibrated arm at axis value
            ``v`` is where the nominal model puts it at ``v + shift``.
        unit: the controller's unit (``deg``, ``rad``, ``counts``; ``m`` for a linear axis).
    """

    axis: str
    shift: float
    unit: str

    def line(self) -> str:
        """``J3 zero: +0.120 deg in controller units``."""
        digits = {"deg": 3, "counts": 1, "m": 6}.get(self.unit, 6)
        return f"{self.axis} zero: {self.shift:+.{digits}f} {self.unit} in controller units"

    def to_dict(self) -> dict[str, Any]:
        return {"axis": self.axis, "shift": self.shift, "unit": self.unit}


def axis_zero_shifts(nominal: Robot, calibrated: Robot, threshold: float = 1e-9
                     ) -> list[ZeroShift]:
    """The controller axes whose zero moved, through the robot's joint map.

    ``da = M^-1 dq / scale`` with ``dq`` from :func:`joint_zero_shifts`: with FANUC's
    coupling a moved J2 zero also moves J3 (by the opposite amount).  Axes that moved less
    than ``threshold`` [rad, m] are left out; a linear axis (one that drives a prismatic
    joint) is given in m.
    """
    cmap = controller_map(nominal)
    da_si = np.linalg.solve(cmap.matrix, joint_zero_shifts(nominal, calibrated))
    prismatic = np.array([j.kind == "prismatic" for j in nominal.joints])
    out = []
    for j, (ax, v) in enumerate(zip(cmap.axes, da_si, strict=True)):
        if abs(v) <= threshold:
            continue
        if np.any(prismatic & (cmap.matrix[:, j] != 0)):    # a linear axis: in m
            out.append(ZeroShift(ax, float(v), "m"))
        else:
            out.append(ZeroShift(ax, float(v / cmap.scale), cmap.unit))
    return out


def calibration_zero_shifts(nominal: Any, calibrated: Any) -> list[ZeroShift] | None:
    """:func:`axis_zero_shifts` for a calibration's nominal and calibrated robots, or
    ``None`` when the robot file declares no controller (no ``controller`` / ``joint_map``
    section: its controller's units are not known) or they are not serial chains with the
    same joints (a five-bar, a robot with held joints whose joint map names the held axes)."""
    if not (isinstance(nominal, Robot) and isinstance(calibrated, Robot)
            and nominal.joint_names == calibrated.joint_names
            and isinstance(nominal.meta.get("controller"), Mapping)):
        return None
    try:
        return axis_zero_shifts(nominal, calibrated)
    except RobotFileError:
        return None
