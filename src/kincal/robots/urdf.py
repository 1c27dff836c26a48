"""URDF front end: the serial chain between two links of a URDF, and URDF export.

Reading (:func:`load_urdf`).  A URDF joint moves its child link relative to its
parent link by

    T_joint(q) = Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll) M(axis, q)

where ``(xyz, rpy)`` is the joint's ``<origin>`` [m, rad] and ``M`` is a rotation by
``q`` [rad] about the unit ``<axis>`` (revolute, continuous) or a translation by
``q`` [m] along it (prismatic); ``M = I`` for a fixed joint.  The chain from
``base_link`` to ``tip_link`` compiles to the elementary transforms of
:mod:`kincal.robots.chain`::

    base frame (6, zero)
    for every joint on the path, base to tip:
        Tx Ty Tz           <joint>.origin.x .y .z     (length; values from the file)
        Rz Ry Rx           yaw, pitch, roll           (fixed constants, not parameters)
        Rx Ry Rz           <joint>.origin.rx .ry .rz  (angle; value 0, see below)
        X(c + s q)         <joint>.offset             (moving joints)
    tool frame (6, zero)

The origin's rotation is the file's ``Rz(yaw) Ry(pitch) Rx(roll)`` held fixed, followed
by small *error* rotations about the frame's own axes, zero at nominal.  Why not make
roll, pitch and yaw the parameters?  Many URDFs place axes with ``pitch = +-pi/2``
(TIAGo's arm_4/5/6, most ``xacro`` wrists); there ``Rz(yaw)`` and ``Rx(roll)`` turn
about the same axis, the rpy Jacobian loses a column, one real rotation direction
per such origin becomes invisible to the identification, and the solver crawls
along the lock.  Error rotations at zero are well conditioned for any nominal
origin (their Jacobian columns are three orthogonal unit axes), and the calibrated
origin is still exactly a URDF origin (:func:`write_calibrated_urdf` composes it).

Which error rotations: all three for fixed and prismatic joints.  A revolute joint
drops the one about the frame axis closest to its own axis: for ``axis = +-e_k``,
``Rk(r) Rk(c + q) = Rk(r + c + q)``, so that rotation *is* the encoder offset and
would only duplicate its column (automatic selection would then keep the origin angle
and call the offset dependent).  For a general axis ``a`` the two kept rotations and
the offset still span every small rotation (``det[e_i, e_j, a] = +-a_k``, ``|a_k| >=
1/sqrt 3``).  So a joint has ``.origin.x .y .z``, two or three of ``.origin.rx .ry
.rz``, and ``.offset`` when it moves.

Fixed joints keep their origin parameters (they are calibration candidates: a
flange or a marker mount is as uncertain as a link).  The motion factor
``X(c + s q)`` carries the joint variable; its constant ``c`` is the encoder zero
offset, zero in the file.  An axis ``+-x, +-y, +-z`` gives ``X = Rx, Ry, Rz`` (``Tx ..``
for prismatic joints) with ``s = +-1``; note that ``c`` turns about (or slides
along) the *positive* coordinate axis, so for a negative axis ``c`` is minus the
offset in joint coordinates.  A general unit axis ``a = (sin t cos f, sin t sin f,
cos t)`` is rotated onto z by fixed constants that are not parameters:
``Rz(f) Ry(t) Rz(c + q) Ry(-t) Rz(-f)`` (``Tz`` for prismatic), which is exactly
the rotation about ``a`` by ``c + q``.

Writing.  :func:`write_urdf` writes any :class:`Robot` (DH, ETS, URDF) as a URDF
whose chain from ``base_link`` to ``tool_link`` has the robot's forward kinematics:
the constant transforms before each joint become that joint's ``<origin>``, the
trailing ones a fixed ``tool_joint``.  :func:`write_calibrated_urdf` copies the
original URDF and rewrites the ``<origin>`` of every joint on the chain with
calibrated values, composing the error rotations and folding each encoder offset
``c`` into it: ``T_origin' = Trans(x, y, z) R_nominal R_error Rot(u, c)`` (revolute)
or ``... R_error Trans(c u)`` (prismatic), ``u`` the axis that ``c`` acts on, written
back as xyz / rpy (:func:`rpy_of` is accurate at ``pitch = +-pi/2``).  Reloading the
written file gives the calibrated kinematics with zero error rotations and offsets.

Masses.  :func:`load_urdf_inertials` reads the ``<inertial>`` of every link that rides on
the chain (mass [kg] and centre of mass ``<origin xyz>`` [m]; the inertia tensor is not
read) as :class:`~kincal.robots.gravity.PointMass` values for
:func:`~kincal.robots.gravity.gravity_torques`: the chain's own links, and every link
hanging off them (fixed joints and side branches with their own moving joints, the
latter held at their zero configuration).

Every problem with a file is one :class:`~kincal.errors.RobotFileError` line naming
the file, the line and the element.  Only the standard library's ElementTree is used.
"""

from __future__ import annotations

import difflib
import io
import math
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError, RobotFileError
from kincal.io import atomic_write_text, read_text
from kincal.robots.chain import ChainBuilder, Robot, elementary_matrix
from kincal.robots.gravity import PointMass
from kincal.robots.urdf_text import mask_comments, set_origin
from kincal.spatial import exp_so3, matrix_to_rpy, rotx, roty, rotz, rpy_near

Array = NDArray[np.float64]

__all__ = ["UrdfInertial", "UrdfJoint", "UrdfModel", "load_urdf", "load_urdf_inertials",
           "parse_urdf", "parse_urdf_inertials", "rpy_of", "urdf_text", "write_calibrated_urdf",
           "write_urdf"]

#: Joint types of the URDF specification.
URDF_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
#: Joint types that can be on a serial chain.
CHAIN_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed")
#: Suffixes of the origin parameters, in chain order: translation, then the error
#: rotations about the frame's own axes after the nominal rotation (a revolute joint
#: has two of the three, see :func:`_error_axes`).
ORIGIN_FIELDS = ("x", "y", "z", "rx", "ry", "rz")
#: A calibrated origin number within this of the file's [m or rad] is the file's number
#: (a picometre / picoradian: far below any calibration, far above rounding noise).
UNCHANGED = 1e-12

_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\Z")
_MAX_LISTED = 10


# --------------------------------------------------------------------------- model
@dataclass(frozen=True)
class UrdfJoint:
    """One ``<joint>`` of a URDF, SI units.

    Attributes:
        name, type, parent, child: as in the file.
        xyz: origin translation [m]; rpy: origin (roll, pitch, yaw) [rad],
            ``R = Rz(yaw) Ry(pitch) Rx(roll)``.
        axis: the unit joint axis in the joint frame (default ``(1, 0, 0)``).
        lower, upper: limits [rad or m], infinite when not given (and for
            continuous joints).
        mimic: the joint this one mimics, or None.
        line: line of the ``<joint>`` element in the file.
        effort, velocity: the ``<limit>``'s effort [N m | N] and velocity [rad/s | m/s],
            None when not given.
    """

    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    lower: float = -math.inf
    upper: float = math.inf
    mimic: str | None = None
    line: int = 0
    effort: float | None = None
    velocity: float | None = None

    @property
    def moving(self) -> bool:
        return self.type in ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class UrdfInertial:
    """The mass properties of one ``<link>`` that :mod:`kincal` uses, SI units.

    Attributes:
        link: the link's name.
        mass: ``<mass value>`` [kg].
        xyz: centre of mass in the link frame, ``<inertial><origin xyz>`` [m].
        rpy: orientation of the inertia frame, ``<origin rpy>`` [rad] (read and
            checked; the centre of mass does not depend on it).
        line: line of the ``<inertial>`` element in the file.
    """

    link: str
    mass: float
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    line: int = 0


@dataclass(frozen=True)
class UrdfModel:
    """The kinematic tree of a URDF file (links and joints, nothing else).

    Attributes:
        name: ``<robot name>`` (the file stem when absent).
        source: the file path, as given.
        links: link name -> line of its ``<link>`` element.
        joints: joint name -> :class:`UrdfJoint`, in file order.
    """

    name: str
    source: str
    links: dict[str, int]
    joints: dict[str, UrdfJoint]
    parent_joint: dict[str, str] = field(default_factory=dict)
    child_joints: dict[str, list[str]] = field(default_factory=dict)

    def fail(self, message: str) -> RobotFileError:
        return RobotFileError(message, source=self.source)

    def roots(self) -> list[str]:
        """Links without a parent joint, in file order."""
        return [n for n in self.links if n not in self.parent_joint]

    def leaves_below(self, link: str) -> list[str]:
        """Links without child joints in the subtree of ``link`` (depth first, file order)."""
        out, stack = [], [link]
        while stack:
            name = stack.pop()
            kids = [self.joints[j].child for j in self.child_joints.get(name, [])]
            if not kids:
                out.append(name)
            stack.extend(reversed(kids))
        return out

    def _known_link(self, name: str, what: str) -> str:
        if name not in self.links:
            close = difflib.get_close_matches(name, list(self.links), n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise self.fail(f"{what} {name!r} is not a link of robot {self.name!r}{hint}")
        return name

    def _moves_below(self, base: str, leaf: str) -> bool:
        """True when a moving joint lies between ``base`` and its descendant ``leaf``."""
        link = leaf
        while link != base:
            j = self.joints[self.parent_joint[link]]
            if j.moving:
                return True
            link = j.parent
        return False

    def chain(self, base_link: str | None = None, tip_link: str | None = None
              ) -> tuple[str, str, list[UrdfJoint]]:
        """The joints from ``base_link`` down to ``tip_link``, base first.

        Defaults: base = the root link; tip = the single leaf below base, or else the
        single leaf reached through a moving joint: leaves fixed rigidly to ``base``
        (ROS-Industrial's ``base`` frame beside ``base_link``) are static frames, not
        the end of the arm.
        """
        if base_link is None:
            roots = self.roots()
            if len(roots) != 1:
                raise self.fail(f"robot {self.name!r} has several root links "
                                f"({_listing(roots)}); choose one with --base-link")
            base = roots[0]
        else:
            base = self._known_link(base_link, "base link")
        if tip_link is None:
            leaves = self.leaves_below(base)
            moving = [leaf for leaf in leaves if self._moves_below(base, leaf)]
            if len(leaves) == 1:
                tip = leaves[0]
            elif len(moving) == 1:
                tip = moving[0]     # the others are static frames (ROS-Industrial's ``base``)
            else:
                raise self.fail(f"link {base!r} has {len(leaves)} leaf links below it "
                                f"({_listing(leaves)}); choose the tip with --tip-link")
        else:
            tip = self._known_link(tip_link, "tip link")
        path: list[UrdfJoint] = []
        link = tip
        while link != base:
            jn = self.parent_joint.get(link)
            if jn is None:
                raise self.fail(f"tip link {tip!r} is not below base link {base!r} "
                                "(it is not one of its descendants)")
            path.append(self.joints[jn])
            link = path[-1].parent
        path.reverse()
        for j in path:
            where = f"line {j.line}: joint {j.name!r}"
            if j.type not in CHAIN_JOINT_TYPES:
                raise self.fail(f"{where} is {j.type}; only revolute, continuous, prismatic "
                                f"and fixed joints can be on the chain {base} -> {tip}")
            if j.mimic is not None:
                raise self.fail(f"{where} mimics joint {j.mimic!r}; mimic (coupled) joints "
                                f"on the chain {base} -> {tip} are not supported")
        if not any(j.moving for j in path):
            raise self.fail(f"the chain {base} -> {tip} has no moving joint")
        return base, tip, path


def _listing(names: Sequence[str]) -> str:
    shown = ", ".join(names[:_MAX_LISTED])
    more = len(names) - _MAX_LISTED
    return shown + (f" and {more} more" if more > 0 else "")


# --------------------------------------------------------------------------- parsing
class _LineTreeBuilder(ET.TreeBuilder):
    """TreeBuilder that remembers the line of every element's start tag."""

    def __init__(self) -> None:
        super().__init__(insert_comments=True, insert_pis=True)
        self.line = 0
        self.lines: dict[int, int] = {}

    def start(self, tag: str, attrs: dict[str, str]) -> ET.Element:
        elem = super().start(tag, attrs)
        self.lines[id(elem)] = self.line
        return elem


def _parse_xml(text: str, source: str) -> tuple[ET.Element, dict[int, int]]:
    """Parse XML text fed line by line, so each element knows its line number."""
    builder = _LineTreeBuilder()
    parser = ET.XMLParser(target=builder)
    try:
        for i, line in enumerate(io.StringIO(text), start=1):  # splits at "\n" only
            builder.line = i
            parser.feed(line)
        root = parser.close()
    except ET.ParseError as exc:
        line_no, col = exc.position
        msg = str(exc).split(":")[0]
        raise RobotFileError(f"line {line_no} column {col + 1}: malformed XML ({msg})",
                             source=source) from None
    return root, builder.lines


class _Fields:
    """Number parsing with one-line errors naming file, line, element and attribute."""

    def __init__(self, source: str, lines: dict[int, int]) -> None:
        self.source = source
        self.lines = lines

    def fail(self, elem: ET.Element, what: str, message: str) -> RobotFileError:
        return RobotFileError(f"line {self.lines.get(id(elem), 0)}: {what}: {message}",
                              source=self.source)

    def number(self, elem: ET.Element, attr: str, what: str) -> float:
        text = elem.get(attr, "").strip()
        return self._num(text, elem, f"{what} <{elem.tag} {attr}={text!r}>")

    def _num(self, text: str, elem: ET.Element, where: str) -> float:
        if not _NUMBER.match(text):
            try:
                value = float(text)
            except ValueError:
                value = 0.0
            if not math.isfinite(value):
                raise self.fail(elem, where, f"{text!r} is not a finite number")
            raise self.fail(elem, where, f"{text!r} is not a number")
        return float(text)

    def vector(self, elem: ET.Element | None, attr: str, what: str,
               default: tuple[float, float, float]) -> tuple[float, float, float]:
        if elem is None or elem.get(attr) is None:
            return default
        text = elem.get(attr, "")
        where = f"{what} <{elem.tag} {attr}={text!r}>"
        parts = text.split()
        if len(parts) != 3:
            raise self.fail(elem, where, f"needs 3 numbers, got {len(parts)}")
        x, y, z = (self._num(p, elem, where) for p in parts)
        return (x, y, z)


def _joint(elem: ET.Element, f: _Fields) -> UrdfJoint:
    line = f.lines.get(id(elem), 0)
    name = elem.get("name")
    if not name:
        raise f.fail(elem, "<joint>", "has no name attribute")
    what = f"joint {name!r}"
    jtype = elem.get("type")
    if jtype not in URDF_JOINT_TYPES:
        raise f.fail(elem, what, f"unknown type {jtype!r} (URDF types: "
                     f"{', '.join(URDF_JOINT_TYPES)})")
    ends = {}
    for tag in ("parent", "child"):
        sub = elem.find(tag)
        if sub is None or not sub.get("link"):
            raise f.fail(elem, what, f"has no <{tag} link=...>")
        ends[tag] = sub.get("link", "")
    origin = elem.find("origin")
    xyz = f.vector(origin, "xyz", what, (0.0, 0.0, 0.0))
    rpy = f.vector(origin, "rpy", what, (0.0, 0.0, 0.0))
    axis = (1.0, 0.0, 0.0)
    ax_elem = elem.find("axis")
    if jtype in ("revolute", "continuous", "prismatic"):
        axis = f.vector(ax_elem, "xyz", what, axis)
        norm = math.sqrt(sum(a * a for a in axis))
        if norm == 0.0:
            raise f.fail(ax_elem if ax_elem is not None else elem, what,
                         "<axis xyz> is zero; a moving joint needs a direction")
        axis = (axis[0] / norm, axis[1] / norm, axis[2] / norm)
    lower, upper = -math.inf, math.inf
    lim = elem.find("limit")
    if lim is not None and jtype in ("revolute", "prismatic"):
        if lim.get("lower") is not None:
            lower = f.number(lim, "lower", what)
        if lim.get("upper") is not None:
            upper = f.number(lim, "upper", what)
        if lower > upper:
            raise f.fail(lim, what, f"<limit> has lower > upper ({lower} > {upper})")
    dyn: dict[str, float | None] = {"effort": None, "velocity": None}
    if lim is not None:
        for key in dyn:
            if lim.get(key) is not None:
                dyn[key] = f.number(lim, key, what)
    mimic_elem = elem.find("mimic")
    mimic = None if mimic_elem is None else (mimic_elem.get("joint") or "?")
    return UrdfJoint(name, jtype, ends["parent"], ends["child"], xyz, rpy, axis,
                     lower, upper, mimic, line, dyn["effort"], dyn["velocity"])


def _model(root: ET.Element, lines: dict[int, int], source: str) -> UrdfModel:
    f = _Fields(source, lines)
    if root.tag != "robot":
        raise f.fail(root, f"<{root.tag}>", "the root element must be <robot>")
    name = root.get("name") or Path(source).stem
    links: dict[str, int] = {}
    joints: dict[str, UrdfJoint] = {}
    for elem in root:
        if elem.tag == "link":
            ln = elem.get("name")
            if not ln:
                raise f.fail(elem, "<link>", "has no name attribute")
            if ln in links:
                raise f.fail(elem, f"link {ln!r}", f"is declared twice (first at line {links[ln]})")
            links[ln] = lines.get(id(elem), 0)
        elif elem.tag == "joint":
            j = _joint(elem, f)
            if j.name in joints:
                raise f.fail(elem, f"joint {j.name!r}",
                             f"is declared twice (first at line {joints[j.name].line})")
            joints[j.name] = j
    if not links:
        raise RobotFileError("the URDF declares no <link>", source=source)
    parent_joint: dict[str, str] = {}
    child_joints: dict[str, list[str]] = {}
    for j in joints.values():
        where = f"line {j.line}: joint {j.name!r}"
        for tag, ln in (("parent", j.parent), ("child", j.child)):
            if ln not in links:
                close = difflib.get_close_matches(ln, list(links), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                raise RobotFileError(f"{where}: <{tag} link={ln!r}> names a link that is not "
                                     f"declared{hint}", source=source)
        if j.parent == j.child:
            raise RobotFileError(f"{where}: joins link {j.child!r} to itself (a loop)",
                                 source=source)
        if j.child in parent_joint:
            other = joints[parent_joint[j.child]]
            raise RobotFileError(f"{where}: link {j.child!r} already has parent joint "
                                 f"{other.name!r} (line {other.line}); a link with two parent "
                                 "joints closes a kinematic loop, which URDF cannot describe",
                                 source=source)
        parent_joint[j.child] = j.name
        child_joints.setdefault(j.parent, []).append(j.name)
    # Each link has at most one parent: a cycle is a walk upwards that comes back.
    state: dict[str, int] = {}
    for start in links:
        walk, link = [], start
        while link in parent_joint and state.get(link) is None:
            state[link] = 1
            walk.append(link)
            link = joints[parent_joint[link]].parent
            if state.get(link) == 1:
                j = joints[parent_joint[link]]
                raise RobotFileError(f"line {j.line}: joint {j.name!r}: the joints form a "
                                     f"closed loop through link {link!r}", source=source)
        for w in walk:
            state[w] = 2
    return UrdfModel(name, source, links, joints, parent_joint, child_joints)


def parse_urdf(path: str | os.PathLike[str]) -> UrdfModel:
    """Read the kinematic tree of a URDF file (links and joints).

    Raises a one-line :class:`RobotFileError` (file, line, element) for malformed
    XML, a root element that is not ``<robot>``, unnamed or repeated links and
    joints, unknown joint types, joints naming undeclared links, links with two
    parent joints (loops), non-numeric or non-finite ``xyz``/``rpy``/``axis``/limits,
    zero axes of moving joints and ``lower > upper``.
    """
    source = str(path)
    root, lines = _parse_xml(read_text(path, "URDF file", RobotFileError), source)
    return _model(root, lines, source)


def _inertials(root: ET.Element, lines: dict[int, int], source: str) -> dict[str, UrdfInertial]:
    """``{link: UrdfInertial}`` of the links that have an ``<inertial>``."""
    f = _Fields(source, lines)
    out: dict[str, UrdfInertial] = {}
    for elem in root:
        if elem.tag != "link" or elem.find("inertial") is None:
            continue
        ln = elem.get("name", "")
        inert = elem.find("inertial")
        assert inert is not None
        what = f"link {ln!r} <inertial>"
        mass_elem = inert.find("mass")
        if mass_elem is None or mass_elem.get("value") is None:
            raise f.fail(inert, what, "has no <mass value=...>")
        mass = f.number(mass_elem, "value", what)
        if mass < 0.0:
            raise f.fail(mass_elem, what, f"<mass value> is negative ({mass} kg)")
        origin = inert.find("origin")
        xyz = f.vector(origin, "xyz", what, (0.0, 0.0, 0.0))
        rpy = f.vector(origin, "rpy", what, (0.0, 0.0, 0.0))
        out[ln] = UrdfInertial(ln, mass, xyz, rpy, lines.get(id(inert), 0))
    return out


def parse_urdf_inertials(path: str | os.PathLike[str]) -> dict[str, UrdfInertial]:
    """The ``<inertial>`` mass and centre of mass of every link that has one.

    Links without ``<inertial>`` are absent (massless).  Raises a one-line
    :class:`RobotFileError` (file, line, link) for everything :func:`parse_urdf`
    rejects, and for an ``<inertial>`` without ``<mass value>``, a non-numeric or
    negative mass, or a malformed ``<origin xyz/rpy>``.
    """
    source = str(path)
    root, lines = _parse_xml(read_text(path, "URDF file", RobotFileError), source)
    _model(root, lines, source)                     # the tree must be valid too
    return _inertials(root, lines, source)


# --------------------------------------------------------------------------- compiling
def _motion_axis(axis: Sequence[float]) -> tuple[int, float, float, float]:
    """How a unit ``axis`` is compiled: ``(k, s, f, t)``.

    ``k`` in {0, 1, 2} and ``s = +-1`` when ``axis = s e_k``; otherwise ``k = -1`` and
    ``(f, t)`` are the azimuth and polar angle with ``Rz(f) Ry(t) e_z = axis``.
    """
    a = [float(v) for v in axis]
    for k in range(3):
        others = [a[i] for i in range(3) if i != k]
        if others == [0.0, 0.0] and a[k] != 0.0:
            return k, math.copysign(1.0, a[k]), 0.0, 0.0
    return -1, 1.0, math.atan2(a[1], a[0]), math.atan2(math.hypot(a[0], a[1]), a[2])


def _offset_axis(axis: Sequence[float]) -> Array:
    """The unit vector that the ``<joint>.offset`` constant turns about / slides along."""
    k, s, _, _ = _motion_axis(axis)
    return np.asarray(axis, dtype=float) * s if k >= 0 else np.asarray(axis, dtype=float)


def _error_axes(j: UrdfJoint) -> tuple[int, ...]:
    """Frame axes (0, 1, 2 = x, y, z) of the origin error rotations of joint ``j``.

    All three for fixed and prismatic joints.  A revolute joint drops the one closest
    to its axis (``argmax |a_k|``): for ``a = +-e_k`` the error rotation about ``e_k``
    is the very transform the encoder offset is (``Rk(r) Rk(c + q) = Rk(r + c + q)``);
    for a general axis the two kept ones and the offset still span every small
    rotation (``det[e_i, e_j, a] = +-a_k != 0``).
    """
    if j.type in ("revolute", "continuous"):
        k = max(range(3), key=lambda i: abs(j.axis[i]))
        return tuple(i for i in range(3) if i != k)
    return (0, 1, 2)


def _compile(model: UrdfModel, base: str, tip: str, path: list[UrdfJoint]) -> Robot:
    b = ChainBuilder(model.name)
    b.frame("base", [0.0] * 6)
    for j in path:
        for fld, v in zip("xyz", j.xyz, strict=True):
            b.transform("T" + fld, f"{j.name}.origin.{fld}", v, role="length")
        roll, pitch, yaw = j.rpy
        for kind, v in (("Rz", yaw), ("Ry", pitch), ("Rx", roll)):
            if v != 0.0:
                b.transform(kind, None, v)            # nominal rotation: fixed constants
        for k in _error_axes(j):
            b.transform("R" + "xyz"[k], f"{j.name}.origin.r{'xyz'[k]}", 0.0, role="angle")
        if not j.moving:
            continue
        revolute = j.type != "prismatic"
        lo, hi = (-math.inf, math.inf) if j.type == "continuous" else (j.lower, j.upper)
        ji = b.joint(j.name, "revolute" if revolute else "prismatic", lo, hi)
        letter = "R" if revolute else "T"
        k, s, f, t = _motion_axis(j.axis)
        if k >= 0:
            b.transform(letter + "xyz"[k], f"{j.name}.offset", 0.0, role="offset",
                        joint=ji, scale=s)
            continue
        align = [("Rz", f), ("Ry", t)]
        for kind, v in align:
            if v != 0.0:
                b.transform(kind, None, v)
        b.transform(letter + "z", f"{j.name}.offset", 0.0, role="offset", joint=ji)
        for kind, v in reversed(align):
            if v != 0.0:
                b.transform(kind, None, -v)
    b.frame("tool", [0.0] * 6)
    meta = {"convention": "urdf", "source": model.source,
            "urdf_file": str(Path(model.source).resolve()), "base_link": base,
            "tip_link": tip, "urdf_robot_name": model.name,
            "joint_effort_velocity": {j.name: [j.effort, j.velocity] for j in path
                                      if j.moving and (j.effort is not None
                                                       or j.velocity is not None)}}
    return b.build(meta=meta)


def load_urdf(path: str | os.PathLike[str], base_link: str | None = None,
              tip_link: str | None = None) -> Robot:
    """Load the serial chain of a URDF file between two links as a :class:`Robot`.

    Args:
        path: the URDF file.
        base_link: first link of the chain; default the URDF's root link.
        tip_link: last link; default the single leaf below ``base_link`` (a clear
            error lists the leaves when there are several).

    Returns:
        A robot with zero base and tool frames; per joint on the path the origin
        translation ``<joint>.origin.x .y .z`` [m] (the file's values), error
        rotations ``<joint>.origin.rx .ry .rz`` [rad] (zero; a revolute joint lacks
        the one about its own axis, which is its offset) after the file's fixed
        nominal rotation, and an encoder offset ``<joint>.offset`` [rad or m] per
        moving joint (see the module docstring for the compiled sequence).  Joint
        limits come from ``<limit lower upper>`` (a missing bound is infinite;
        continuous joints are unlimited).  ``meta`` holds ``convention="urdf"``,
        ``source``, ``urdf_file``, ``base_link``, ``tip_link`` and ``urdf_robot_name``.

    Raises:
        RobotFileError: one line naming the file, line and element (see
        :func:`parse_urdf`), plus: unknown links, a tip not below the base, several
        leaves, floating/planar or mimic joints on the chain.
    """
    model = parse_urdf(path)
    base, tip, chain = model.chain(base_link, tip_link)
    return _compile(model, base, tip, chain)


def _origin_matrix(j: UrdfJoint) -> Array:
    """``Trans(xyz) Rz(yaw) Ry(pitch) Rx(roll)`` of a joint's nominal ``<origin>``."""
    T = np.eye(4)
    roll, pitch, yaw = j.rpy
    T[:3, :3] = rotz(yaw) @ roty(pitch) @ rotx(roll)
    T[:3, 3] = j.xyz
    return T


def _carrier_to_link(j: UrdfJoint) -> Array:
    """Child link frame of moving joint ``j`` in the frame just after its motion factor.

    Identity for a coordinate axis (the factor ends the joint); for a general axis the
    alignment is undone after ``Rz(c + q)``: ``Ry(-t) Rz(-f)`` (see :func:`_compile`).
    """
    k, _, f, t = _motion_axis(j.axis)
    if k >= 0:
        return np.eye(4)
    T = np.eye(4)
    for kind, v in (("Ry", t), ("Rz", f)):
        if v != 0.0:
            T = T @ elementary_matrix(kind, -v)
    return T


def load_urdf_inertials(path: str | os.PathLike[str], base_link: str | None = None,
                        tip_link: str | None = None) -> list[PointMass]:
    """The masses riding on the chain ``base_link -> tip_link`` of a URDF, for
    :func:`kincal.robots.gravity.gravity_torques` with ``load_urdf(path, base_link,
    tip_link)``.

    Which links: ``base_link``, every link of the chain, and every link below a chain
    link that is not itself on the chain (a flange, a sensor or a gripper attached by
    fixed joints; a side branch with moving joints of its own, such as fingers or a
    head, *held at its zero configuration*: its joints are not part of the model).
    Links above ``base_link`` or in other subtrees of the root are not included.
    Links without ``<inertial>`` are massless and omitted.

    Each link gives ``PointMass(joint, mass, com, name=link)``: ``joint`` is the index
    (in ``robot.joints``) of the last moving joint between ``base_link`` and the link,
    ``-1`` before the first one; ``com`` [m] is the link's ``<inertial><origin xyz>``
    carried, through the nominal ``<origin>`` transforms of the joints in between (side
    joints at zero), into the frame just after that joint's motion factor ``X(c + s q)``
    (for ``-1``: the frame of ``base_link``, which is the robot's reference frame with
    zero base parameters).  Origins use the file's nominal values; a calibration's
    small corrections move the masses by the same small amounts (negligible in the
    torques).

    Raises:
        RobotFileError: as :func:`load_urdf` and :func:`parse_urdf_inertials`.
    """
    source = str(path)
    root, lines = _parse_xml(read_text(path, "URDF file", RobotFileError), source)
    model = _model(root, lines, source)
    inertials = _inertials(root, lines, source)
    base, _, chain = model.chain(base_link, tip_link)
    on_chain = {j.name for j in chain}
    out: list[PointMass] = []

    def collect(link: str, T: Array, rider: int) -> None:
        """``link`` and everything hanging off it (not the chain's next joint)."""
        stack = [(link, T)]
        while stack:
            name, Tl = stack.pop()
            inert = inertials.get(name)
            if inert is not None and inert.mass > 0.0:
                c = Tl[:3, :3] @ np.asarray(inert.xyz) + Tl[:3, 3]
                out.append(PointMass(rider, inert.mass, (float(c[0]), float(c[1]), float(c[2])),
                                     name))
            for jn in reversed(model.child_joints.get(name, [])):
                if jn not in on_chain:
                    sub = model.joints[jn]
                    stack.append((sub.child, Tl @ _origin_matrix(sub)))

    rider = -1
    T = np.eye(4)
    collect(base, T, rider)
    for j in chain:
        T = T @ _origin_matrix(j)
        if j.moving:
            rider += 1
            T = _carrier_to_link(j)
        collect(j.child, T, rider)
    return out


# --------------------------------------------------------------------------- geometry
def rpy_of(R: Array) -> tuple[float, float, float]:
    """Roll, pitch, yaw [rad] with ``R = Rz(yaw) Ry(pitch) Rx(roll)``, accurate at gimbal lock.

    ``yaw = atan2(R21, R11)``; with ``M = Rz(-yaw) R = Ry(pitch) Rx(roll)`` (its
    ``M21`` vanishes by construction), ``pitch = atan2(-R31, M11)`` and
    ``roll = atan2(-M23, M22)``.  Every angle comes from O(1) entries, so
    ``Rz Ry Rx`` of the result reproduces ``R`` to rounding error even when
    ``cos(pitch)`` is tiny (where ``atan2(R32, R33)`` for roll would lose digits).
    """
    roll, pitch, yaw = matrix_to_rpy(R)
    return float(roll), float(pitch), float(yaw)


def _fmt(values: Sequence[float] | NDArray[np.float64]) -> str:
    """Shortest text that reads back as the same floats (whole numbers without ``.0``)."""
    return " ".join(str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else repr(float(v))
                    for v in values)


def _unchanged_kept(new: Sequence[float] | Array, old: Sequence[float]) -> Array:
    """``new`` with every number within :data:`UNCHANGED` of the file's ``old`` one set to
    it exactly, so rounding noise of the origin's recomposition (1e-13 .. 1e-26) is not
    written into a number the calibration did not change; the others rounded to 13
    decimals, below which the recomposition's digits are noise."""
    n = np.array(new, dtype=float)
    o = np.asarray(old, dtype=float)
    # a changed number to 13 decimals (0.30005, not 0.3000499999999999): 5e-14 m or rad
    return np.where(np.abs(n - o) <= UNCHANGED, o, np.round(n, 13))


def _origin_attrs(T: Array) -> dict[str, str]:
    return {"xyz": _fmt(T[:3, 3]), "rpy": _fmt(rpy_of(T[:3, :3]))}


# --------------------------------------------------------------------------- writing
def _unique(name: str, taken: set[str]) -> str:
    out, i = name, 1
    while out in taken:
        out = f"{name}_{i}"
        i += 1
    taken.add(out)
    return out


def _limit_elem(parent: ET.Element, lower: float, upper: float,
                dynamics: Sequence[float | None] | None = None) -> None:
    """``<limit>``: the bounds, and the effort and velocity only when known (a kinematic
    model has none; writing 0 would tell a controller the joint may not move)."""
    attrs = {}
    if math.isfinite(lower):
        attrs["lower"] = _fmt([lower])
    if math.isfinite(upper):
        attrs["upper"] = _fmt([upper])
    effort, velocity = (list(dynamics or []) + [None, None])[:2]
    if effort is not None:
        attrs["effort"] = _fmt([effort])
    if velocity is not None:
        attrs["velocity"] = _fmt([velocity])
    if effort is None or velocity is None:
        parent.append(ET.Comment(" effort and velocity unknown (a kinematic model): take "
                                 "them from the robot's datasheet before a controller uses "
                                 "this file "))
    ET.SubElement(parent, "limit", attrs)


def urdf_text(robot: Robot, name: str | None = None) -> tuple[str, str, str]:
    """The URDF document written by :func:`write_urdf`: ``(text, base_link, tip_link)``."""
    values = robot.param_values
    links: set[str] = set()
    joint_names: set[str] = {j.name for j in robot.joints}
    root = ET.Element("robot", {"name": name or robot.name})
    base = parent = _unique("base_link", links)
    ET.SubElement(root, "link", {"name": parent})
    M = np.eye(4)
    for et in robot.ets:
        c = float(values[et.param]) if et.param >= 0 else et.constant
        M = M @ elementary_matrix(et.kind, c)
        if et.joint < 0:
            continue
        jt = robot.joints[et.joint]
        child = _unique(jt.name + "_link", links)
        ET.SubElement(root, "link", {"name": child})
        revolute = jt.kind == "revolute"
        unlimited = not (math.isfinite(jt.lower) or math.isfinite(jt.upper))
        jtype = ("continuous" if unlimited else "revolute") if revolute else "prismatic"
        je = ET.SubElement(root, "joint", {"name": jt.name, "type": jtype})
        ET.SubElement(je, "origin", _origin_attrs(M))
        ET.SubElement(je, "parent", {"link": parent})
        ET.SubElement(je, "child", {"link": child})
        axis = np.zeros(3)
        axis["xyz".index(et.kind[1])] = et.scale
        ET.SubElement(je, "axis", {"xyz": _fmt(axis)})
        if jtype != "continuous":
            _limit_elem(je, jt.lower, jt.upper,
                        dict(robot.meta.get("joint_effort_velocity") or {}).get(jt.name))
        parent, M = child, np.eye(4)
    tip = _unique("tool_link", links)
    ET.SubElement(root, "link", {"name": tip})
    je = ET.SubElement(root, "joint", {"name": _unique("tool_joint", joint_names),
                                       "type": "fixed"})
    ET.SubElement(je, "origin", _origin_attrs(M))
    ET.SubElement(je, "parent", {"link": parent})
    ET.SubElement(je, "child", {"link": tip})
    conv = robot.meta.get("convention", "ets")
    root.insert(0, ET.Comment(f" written by kincal from robot {robot.name!r} (convention {conv}): "
                              f"forward kinematics from {base} to {tip} equal the model's "))
    ET.indent(root, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n", base, tip


def write_urdf(robot: Robot, path: str | os.PathLike[str], name: str | None = None
               ) -> tuple[str, str]:
    """Write any serial :class:`Robot` as a URDF with the same forward kinematics.

    The chain ``E_1 ... E_K`` is cut after each joint factor ``X_k(c_k + s q)``: the
    product of the constant factors since the previous joint, times ``X_k(c_k)``,
    becomes the joint's ``<origin>`` (xyz, rpy = Rz Ry Rx); its ``<axis>`` is
    ``s e_k``.  The trailing constants (tool frame included) become a fixed
    ``tool_joint``.  Links: ``base_link``, ``<joint>_link`` per joint and
    ``tool_link`` (a suffix ``_1`` ... is added to a name already taken).
    Unlimited revolute joints are written as ``continuous``; infinite bounds of
    other joints are left out of ``<limit>``; ``effort`` and ``velocity`` are written
    when the robot came from a URDF that gave them, else left out with a comment saying
    they are unknown (the file is a kinematic model).  Atomic write; ``"-"`` writes to stdout.

    Returns:
        The written file's first and last link names ``(base_link, tip_link)``, such that
        ``load_urdf(path, base_link, tip_link).fk(q) == robot.fk(q)``.
    """
    text, base, tip = urdf_text(robot, name)
    atomic_write_text(path, text)
    return base, tip


def write_calibrated_urdf(original_urdf: str | os.PathLike[str] | None, robot: Robot,
                          path: str | os.PathLike[str], base_name: str = "calibrated_base",
                          tool_name: str = "calibrated_tool") -> tuple[str, str]:
    """Copy a URDF with the calibrated joint origins of ``robot`` written in.

    ``robot`` must come from :func:`load_urdf` on ``original_urdf`` (same chain, same
    parameter names and nominal origins), with any parameter values.  For every joint
    on its chain the ``<origin>`` becomes ``Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)``
    (the file's nominal rotation) times the calibrated error rotations
    (``Rx(rx) Ry(ry) Rz(rz)``, those the joint has), times the folded encoder offset
    ``c``: ``Rot(u, c)`` for a revolute joint, ``Trans(c u)`` for a prismatic one,
    ``u`` the axis ``c`` acts on (so the joint readings ``q`` are unchanged).
    The file is edited as text (:mod:`kincal.robots.urdf_text`): only the changed numbers of
    the chain's ``<origin>`` attributes differ, so the calibrated URDF reviews as a
    minimal diff in version control; everything else (formatting, comments, attribute
    order, other branches, inertias, meshes) is kept byte for byte.

    A non-zero calibrated base frame is written as a new root link ``base_name``
    with a fixed joint to ``base_link`` (which must then be the URDF's root); a
    non-zero tool frame as a new link ``tool_name`` fixed to ``tip_link``.

    Returns:
        ``(base, tip)``: the links of the written file between which the forward
        kinematics equal ``robot.fk`` (``load_urdf(path, base, tip)``).
    """
    if robot.meta.get("convention") != "urdf" or "tip_link" not in robot.meta:
        raise KincalError(f"robot {robot.name!r} was not loaded from a URDF (convention "
                          f"{robot.meta.get('convention')!r}); use write_urdf")
    if original_urdf is None:
        original_urdf = robot.meta["urdf_file"]
    source = str(original_urdf)
    text = read_text(original_urdf, "URDF file", RobotFileError)
    root, lines = _parse_xml(text, source)
    model = _model(root, lines, source)
    base, tip = str(robot.meta["base_link"]), str(robot.meta["tip_link"])
    _, _, chain = model.chain(base, tip)
    nominal = _compile(model, base, tip, chain)
    if nominal.param_names != robot.param_names:
        raise RobotFileError(f"robot {robot.name!r} does not match the chain {base} -> {tip} "
                             "of this file (different parameters)", source=source)
    if nominal.ets != robot.ets:
        raise RobotFileError(f"robot {robot.name!r} does not match the chain {base} -> {tip} "
                             "of this file (different nominal origins or axes)", source=source)
    v = robot.params()
    try:        # the bytes as they are (CRLF, BOM): the output differs only where it must
        out_text = Path(original_urdf).read_bytes().decode("utf-8")
    except (OSError, UnicodeDecodeError):
        out_text = text
    for j in chain:
        pre = f"{j.name}.origin."
        T = np.eye(4)
        T[:3, 3] = [v[pre + fld] for fld in "xyz"]
        roll, pitch, yaw = j.rpy
        T[:3, :3] = rotz(yaw) @ roty(pitch) @ rotx(roll)
        for k in _error_axes(j):
            T = T @ elementary_matrix("R" + "xyz"[k], v[f"{pre}r{'xyz'[k]}"])
        if j.moving:
            c = v[f"{j.name}.offset"]
            u = _offset_axis(j.axis)
            F = np.eye(4)
            if j.type == "prismatic":
                F[:3, 3] = c * u
            else:
                F[:3, :3] = exp_so3(np.asarray(u, dtype=float) * c)
            T = T @ F
        xyz = _unchanged_kept(T[:3, 3], j.xyz)
        rpy = _unchanged_kept(rpy_near(T[:3, :3], j.rpy, UNCHANGED), j.rpy)
        if np.allclose(xyz, j.xyz, rtol=0, atol=0) and np.allclose(rpy, j.rpy, rtol=0, atol=0):
            continue                        # untouched: not a byte of it changes
        out_text = set_origin(out_text, j.name, xyz, rpy, _fmt)
    links = set(model.links)
    joint_names = set(model.joints)
    out_base, out_tip = base, tip
    added: list[str] = []

    def frame_joint(prefix: str, parent: str, child: str, xyzrpy: Array) -> None:
        # Trans(x, y, z) Rz Ry Rx is a URDF origin as it is: xyz, rpy = (rx, ry, rz)
        a = {"xyz": _fmt(xyzrpy[:3]), "rpy": _fmt(xyzrpy[[5, 4, 3]])}
        added.append(f'  <joint name="{_unique(f"{prefix}_joint", joint_names)}" type="fixed">\n'
                     f'    <origin xyz="{a["xyz"]}" rpy="{a["rpy"]}"/>\n'
                     f'    <parent link="{parent}"/>\n    <child link="{child}"/>\n  </joint>')

    base_vals = np.array([v[f"base.{k}"] for k in ("x", "y", "z", "rz", "ry", "rx")])
    tool_vals = np.array([v[f"tool.{k}"] for k in ("x", "y", "z", "rz", "ry", "rx")])
    if np.any(base_vals != 0.0):
        if base in model.parent_joint:
            raise RobotFileError(f"cannot write the calibrated base frame: base link {base!r} "
                                 f"has parent joint {model.parent_joint[base]!r}", source=source)
        out_base = _unique(base_name, links)
        added.append(f'  <link name="{out_base}"/>  <!-- calibrated by kincal: base frame -->')
        frame_joint(out_base, out_base, base, base_vals)
    if np.any(tool_vals != 0.0):
        out_tip = _unique(tool_name, links)
        added.append(f'  <link name="{out_tip}"/>  <!-- calibrated by kincal: tool frame -->')
        frame_joint(out_tip, tip, out_tip, tool_vals)
    if added:
        masked = mask_comments(out_text)
        close = masked.rfind("</robot>")
        newline = "\r\n" if "\r\n" in out_text else "\n"
        block = newline.join("\n".join(added).split("\n")) + newline
        out_text = out_text[:close] + block + out_text[close:]
    atomic_write_text(path, out_text)
    return out_base, out_tip
