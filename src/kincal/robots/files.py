"""Robot files: the YAML format, the built-in library, and one loader for everything.

A robot file is YAML with explicit units::

    name: puma560
    description: Unimation PUMA 560
    source: where the numbers come from
    units: {length: m, angle: deg}        # required: m | mm, rad | deg
    convention: standard_dh               # standard_dh | modified_dh | hayati | ets | urdf
    base: {x: 0, y: 0, z: 0, rx: 0, ry: 0, rz: 0}   # optional, rpy = Rz(rz) Ry(ry) Rx(rx)
    tool: {x: 0, y: 0, z: 0, rx: 0, ry: 0, rz: 0}   # optional
    joints:                                # DH conventions: one row per joint
      - {name: q1, type: revolute, a: 0, d: 0, alpha: 90, theta_offset: 0, limits: [-160, 160]}
      - {name: q2, type: prismatic, a: 0, d: 0, alpha: 0, theta_offset: 0, limits: [0.1, 1]}
      - {..., beta: 0}                     # hayati: an extra Ry(beta) after Rx(alpha)

``convention: ets`` lists joints (``name``, ``type``, ``limits``) and a ``chain`` of
elementary transforms ``{transform: Rz, name: theta_offset[1], value: 0, joint: q1,
scale: 1, role: offset}`` (``name: null`` for a fixed constant).  ``convention: urdf``
points to a URDF file: ``{file: arm.urdf, base_link: base, tip_link: tool0}``.
``kind: fivebar`` files describe the five-bar parallel robot
(:mod:`kincal.parallel.fivebar`).

Joint limits are in the file's angle unit for revolute joints and its length unit
for prismatic ones.  Every error names the file and the field, on one line.

**Joint units of measurement files** (optional, top level)::

    joint_units: si                       # or a mapping {joint name: unit}

``units`` is about the numbers *in the robot file*.  ``joint_units`` is about the
joint columns of *measurement files* for this robot: with ``si`` a bare column named
after a joint (``arm_3_joint``, no ``_deg`` suffix) is read in rad (revolute) or m
(prismatic); a mapping gives the unit per joint (``{q1: deg, q7: mm}``; angle units
``rad deg``, length units ``m mm``).  Without it bare joint columns need ``--units``.
It is read into ``robot.meta["joint_units"]`` (the form
:mod:`kincal.measure.files` consumes) and written back by :func:`write_robot_yaml`;
URDF-derived robots are ``si`` by definition (the URDF standard), so writing one as
YAML sets ``joint_units: si``.

:func:`robot_yaml_text` renders a robot file without writing it;
:func:`write_robot_yaml` writes it atomically.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from kincal.errors import RobotFileError
from kincal.io import atomic_write_text, read_text
from kincal.robots.chain import KINDS, ROLES, ChainBuilder, Robot
from kincal.robots.dh import DHLink, dh_links, from_dh
from kincal.spatial import FRAME_FIELDS
from kincal.units import UNITS

_JOINT_KINDS = ("revolute", "prismatic")

#: Units a robot file may state (``units:``, ``joint_units:``), factors from the one
#: table of :data:`kincal.units.UNITS`.
LENGTH_UNITS = {u: UNITS[u][1] for u in ("m", "mm")}
ANGLE_UNITS = {u: UNITS[u][1] for u in ("rad", "deg")}
CONVENTIONS = ("standard_dh", "modified_dh", "hayati", "ets", "urdf")
_FRAME_KEYS = ("x", "y", "z", "rx", "ry", "rz")


# --------------------------------------------------------------------------- parsing
#: libyaml's loader when PyYAML has it (about 10x faster), else the pure-Python one.
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def yaml_load(text: str) -> Any:
    """``yaml.safe_load`` through libyaml when available (same values, same errors)."""
    return yaml.load(text, Loader=_SAFE_LOADER)  # noqa: S506  (a safe loader)


class FieldReader:
    """Typed access to a YAML mapping, with errors that name the file and the field."""

    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, field: str, what: str) -> RobotFileError:
        return RobotFileError(f"field '{field}' {what}", source=self.source)

    def mapping(self, value: Any, field: str) -> Mapping[str, Any]:
        if not isinstance(value, Mapping):
            raise self.fail(field, f"must be a mapping, got {type(value).__name__}")
        return value

    def get(self, m: Mapping[str, Any], key: str, field: str, default: Any = ...) -> Any:
        if key not in m:
            if default is ...:
                raise self.fail(f"{field}{key}", "is missing")
            return default
        return m[key]

    def number(self, value: Any, field: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(field, f"must be a number, got {value!r}")
        try:
            number = float(value)
        except OverflowError:
            raise self.fail(field, "must be finite, got an integer too large for a float") from None
        if not math.isfinite(number):
            raise self.fail(field, f"must be finite, got {value!r}")
        return number

    def string(self, value: Any, field: str) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(field, f"must be a non-empty string, got {value!r}")
        return value

    def choice(self, value: Any, field: str, options: tuple[str, ...] | list[str]) -> str:
        if value not in options:
            raise self.fail(field, f"must be one of {', '.join(options)}; got {value!r}")
        return str(value)

    def joint_kind(self, value: Any, field: str) -> Literal["revolute", "prismatic"]:
        """``"revolute"`` or ``"prismatic"``; any other value is an error naming ``field``."""
        return "prismatic" if self.choice(value, field, _JOINT_KINDS) == "prismatic" \
            else "revolute"

    def limits(self, value: Any, field: str, scale: float) -> tuple[float, float]:
        if value is None:
            return -math.inf, math.inf
        if not isinstance(value, list | tuple) or len(value) != 2:
            raise self.fail(field, "must be a list [lower, upper]")
        lo = self.number(value[0], f"{field}[0]") * scale
        hi = self.number(value[1], f"{field}[1]") * scale
        if lo > hi:
            raise self.fail(field, f"has lower > upper ({value[0]} > {value[1]})")
        return lo, hi


def read_units(r: FieldReader, data: Mapping[str, Any]) -> tuple[float, float]:
    """The file's ``units: {length: m|mm, angle: rad|deg}`` as SI scale factors."""
    units = r.mapping(r.get(data, "units", ""), "units")
    lu = r.choice(r.get(units, "length", "units."), "units.length", list(LENGTH_UNITS))
    au = r.choice(r.get(units, "angle", "units."), "units.angle", list(ANGLE_UNITS))
    return LENGTH_UNITS[lu], ANGLE_UNITS[au]


def _frame(r: FieldReader, data: Mapping[str, Any], key: str, ls: float, as_: float) -> list[float]:
    if key not in data or data[key] is None:
        return [0.0] * 6
    m = r.mapping(data[key], key)
    unknown = sorted(map(str, set(m) - set(_FRAME_KEYS)))
    if unknown:
        raise r.fail(f"{key}.{unknown[0]}", f"is not a frame field (use {', '.join(_FRAME_KEYS)})")
    return [r.number(m.get(k, 0.0), f"{key}.{k}") * (ls if i < 3 else as_)
            for i, k in enumerate(FRAME_FIELDS)]


def _meta(r: FieldReader, data: Mapping[str, Any], convention: str) -> dict[str, Any]:
    meta: dict[str, Any] = {"convention": convention}
    for key in ("vendor", "description", "source", "notes"):
        if key in data and data[key] is not None:
            meta[key] = str(data[key]).strip()
    tol = _tolerances(r, data)
    if tol:
        meta["tolerances"] = tol
    if "controller" in data and "joint_map" in data:
        raise r.fail("joint_map", "is another name for 'controller': give one of them")
    jmap = data.get("controller", data.get("joint_map"))
    if isinstance(jmap, Mapping):    # read by kincal.robots.controller
        meta["controller"] = dict(jmap)
    if data.get("calibration") is not None:             # read by kincal.identify.envelope
        meta["calibration"] = dict(r.mapping(data["calibration"], "calibration"))
        meta["calibration_source"] = r.source
    if data.get("joint_model") is not None:     # read by kincal.workflow.carried_joint_model
        meta["joint_model"] = dict(r.mapping(data["joint_model"], "joint_model"))
    if data.get("masses") is not None:                  # read by kincal.robots.masses
        meta["masses"] = dict(r.mapping(data["masses"], "masses"))
    return meta


def _tolerances(r: FieldReader, data: Mapping[str, Any]) -> dict[str, str]:
    """The optional ``tolerances:`` section: ``{role, name or pattern: value with unit}``
    (``length: 0.5mm``, ``"d[3]": 2mm``, ``offset: none``), kept as text; its values are
    parsed (units, patterns) by :mod:`kincal.identify.tolerances` when a calibration
    uses them."""
    value = data.get("tolerances")
    if value is None:
        return {}
    m = r.mapping(value, "tolerances")
    out: dict[str, str] = {}
    for key, v in m.items():
        if isinstance(v, bool) or not isinstance(v, str | int | float):
            raise r.fail(f"tolerances.{key}", "must be a value with its unit (e.g. 0.5mm, "
                         f"0.05deg) or none, got {v!r}")
        if isinstance(v, int | float):
            raise r.fail(f"tolerances.{key}", f"needs a unit (e.g. {v}mm or {v}deg)")
        out[str(key)] = v.strip()
    return out


def _joint_units(r: FieldReader, data: Mapping[str, Any], robot: Robot
                 ) -> str | dict[str, str] | None:
    """The optional ``joint_units`` field: ``"si"`` or ``{joint: unit}``, checked against
    the robot's joints (angle units for revolute joints, length units for prismatic)."""
    value = data.get("joint_units")
    if value is None:
        return None
    if isinstance(value, str):
        return r.choice(value, "joint_units", ("si",))
    m = r.mapping(value, "joint_units")
    kinds = {j.name: j.kind for j in robot.joints}
    out: dict[str, str] = {}
    for name, unit in m.items():
        field = f"joint_units.{name}"
        if str(name) not in kinds:
            raise r.fail(field, f"names no joint of the robot (joints: {', '.join(kinds)})")
        allowed = ANGLE_UNITS if kinds[str(name)] == "revolute" else LENGTH_UNITS
        out[str(name)] = r.choice(unit, field, list(allowed))
    return out


def _with_joint_units(r: FieldReader, data: Mapping[str, Any], robot: Robot) -> Robot:
    """``robot`` with ``meta["joint_units"]`` set from the file (unchanged without it)."""
    ju = _joint_units(r, data, robot)
    if ju is None:
        return robot
    return dataclasses.replace(robot, meta={**dict(robot.meta), "joint_units": ju})


def _dh_robot(r: FieldReader, data: Mapping[str, Any], name: str, conv: str) -> Robot:
    ls, as_ = read_units(r, data)
    joints = r.get(data, "joints", "")
    if not isinstance(joints, list) or not joints:
        raise r.fail("joints", "must be a non-empty list of DH rows")
    links = []
    for i, row in enumerate(joints):
        f = f"joints[{i}]"
        row = r.mapping(row, f)
        allowed = {"name", "type", "a", "d", "alpha", "theta_offset", "beta", "limits"}
        extra = sorted(map(str, set(row) - allowed))
        if extra:
            raise r.fail(f"{f}.{extra[0]}", f"is not a DH field (use {', '.join(sorted(allowed))})")
        kind = r.joint_kind(r.get(row, "type", f"{f}."), f"{f}.type")
        beta = None
        if "beta" in row:
            if conv != "hayati":
                raise r.fail(f"{f}.beta", "is only allowed with convention: hayati")
            beta = r.number(row["beta"], f"{f}.beta") * as_
        lscale = as_ if kind == "revolute" else ls
        lo, hi = r.limits(row.get("limits"), f"{f}.limits", lscale)
        jname = r.string(row["name"], f"{f}.name") if "name" in row else f"q{i + 1}"
        links.append(DHLink(
            a=r.number(r.get(row, "a", f"{f}."), f"{f}.a") * ls,
            d=r.number(r.get(row, "d", f"{f}."), f"{f}.d") * ls,
            alpha=r.number(r.get(row, "alpha", f"{f}."), f"{f}.alpha") * as_,
            theta_offset=r.number(row.get("theta_offset", 0.0), f"{f}.theta_offset") * as_,
            joint=kind, beta=beta, name=jname, lower=lo, upper=hi))
    names = [L.name for L in links]
    if len(set(names)) != len(names):
        dup = sorted({str(n) for n in names if names.count(n) > 1})
        raise r.fail("joints", f"has duplicate joint names {dup}")
    return from_dh(links, "modified" if conv == "modified_dh" else "standard", name,
                   _frame(r, data, "base", ls, as_), _frame(r, data, "tool", ls, as_),
                   _meta(r, data, conv))


def _ets_robot(r: FieldReader, data: Mapping[str, Any], name: str) -> Robot:
    ls, as_ = read_units(r, data)
    b = ChainBuilder(name)
    b.frame("base", _frame(r, data, "base", ls, as_))
    joints = r.get(data, "joints", "")
    if not isinstance(joints, list):
        raise r.fail("joints", "must be a list")
    index: dict[str, int] = {}
    kinds: dict[str, str] = {}
    for i, row in enumerate(joints):
        f = f"joints[{i}]"
        row = r.mapping(row, f)
        jn = r.string(r.get(row, "name", f"{f}."), f"{f}.name")
        jkind = r.joint_kind(r.get(row, "type", f"{f}."), f"{f}.type")
        lo, hi = r.limits(row.get("limits"), f"{f}.limits", as_ if jkind == "revolute" else ls)
        if jn in index:
            raise r.fail(f"{f}.name", f"repeats joint {jn!r}")
        index[jn] = b.joint(jn, jkind, lo, hi)
        kinds[jn] = jkind
    chain = r.get(data, "chain", "")
    if not isinstance(chain, list) or not chain:
        raise r.fail("chain", "must be a non-empty list of elementary transforms")
    used: set[str] = set()
    for i, row in enumerate(chain):
        f = f"chain[{i}]"
        row = r.mapping(row, f)
        kind = r.choice(r.get(row, "transform", f"{f}."), f"{f}.transform", KINDS)
        scale = as_ if kind.startswith("R") else ls
        value = r.number(row.get("value", 0.0), f"{f}.value") * scale
        pname = row.get("name")
        if pname is not None:
            pname = r.string(pname, f"{f}.name")
            if pname.startswith(("base.", "tool.")):
                raise r.fail(f"{f}.name", "is reserved for the base and tool frames")
            if pname in b.names:
                raise r.fail(f"{f}.name", f"repeats parameter {pname!r}")
        role = r.choice(row.get("role", "angle" if kind.startswith("R") else "length"),
                        f"{f}.role", ROLES)
        j = -1
        if row.get("joint") is not None:
            jn = r.string(row["joint"], f"{f}.joint")
            if jn not in index:
                raise r.fail(f"{f}.joint", f"names unknown joint {jn!r}")
            if jn in used:
                raise r.fail(f"{f}.joint", f"uses joint {jn!r} a second time")
            want = "revolute" if kind.startswith("R") else "prismatic"
            if kinds[jn] != want:
                raise r.fail(f"{f}.transform", f"{kind} cannot carry {kinds[jn]} joint {jn!r}")
            used.add(jn)
            j = index[jn]
        s = r.number(row.get("scale", 1.0), f"{f}.scale")
        if s not in (1.0, -1.0):
            raise r.fail(f"{f}.scale", "must be 1 or -1")
        b.transform(kind, pname, value, role=role, joint=j, scale=s)
    missing = sorted(set(index) - used)
    if missing:
        raise r.fail("chain", f"never uses joint {missing[0]!r}")
    b.frame("tool", _frame(r, data, "tool", ls, as_))
    return b.build(meta=_meta(r, data, "ets"))


def robot_from_dict(data: Any, source: str) -> Any:
    """Build a robot (serial :class:`Robot` or five-bar) from parsed YAML ``data``."""
    r = FieldReader(source)
    data = r.mapping(data, "(top level)")
    if data.get("kind") == "fivebar":
        raise RobotFileError("kind 'fivebar' is a parallel robot, not a serial chain: load it "
                             "with kincal.load_robot or kincal.parallel.files.load_fivebar",
                             source=source)
    if "kind" in data and data["kind"] != "serial":
        raise r.fail("kind", f"must be 'serial' or 'fivebar', got {data['kind']!r}")
    name = r.string(data.get("name", Path(source).stem), "name")
    conv = r.choice(r.get(data, "convention", ""), "convention", CONVENTIONS)
    if conv == "urdf":
        from kincal.robots.urdf import load_urdf

        f = r.string(r.get(data, "file", ""), "file")
        path = (Path(source).parent / f) if not os.path.isabs(f) else Path(f)
        robot = load_urdf(path, base_link=data.get("base_link"), tip_link=data.get("tip_link"))
        meta = dict(robot.meta)
        meta.update({k: v for k, v in _meta(r, data, "urdf").items() if k != "convention"})
        robot = Robot(name, robot.ets, robot.joints, robot.param_names, robot.param_values,
                      robot.param_units, robot.param_roles, meta)
    elif conv == "ets":
        robot = _ets_robot(r, data, name)
    else:
        robot = _dh_robot(r, data, name, conv)
    return _with_joint_units(r, data, robot)


def read_robot_yaml(path: str | os.PathLike[str]) -> Any:
    """Read a robot YAML file; every problem is a one-line :class:`RobotFileError`."""
    source = str(path)
    text = read_text(path, "robot file", RobotFileError)
    try:
        data = yaml_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1} column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise RobotFileError(f"{where}invalid YAML ({problem})", source=source) from None
    if data is None:
        raise RobotFileError("the file is empty", source=source)
    return robot_from_dict(data, source)


# --------------------------------------------------------------------------- library
def library_dir() -> Path:
    """Folder of the built-in robot files."""
    return Path(str(resources.files("kincal.robots") / "library"))


def library_names() -> list[str]:
    """Names of the built-in robots (file stems), sorted."""
    return sorted(p.stem for p in library_dir().glob("*.yaml"))


def robot_kind(spec: str | os.PathLike[str]) -> str:
    """``"fivebar"`` when ``spec`` names a YAML robot file or built-in robot whose top
    level says ``kind: fivebar``, else ``"serial"``.  Never raises: the loader reports
    any problem with the file."""
    s = str(spec)
    path = Path(s)
    if path.suffix.lower() == ".urdf":
        return "serial"
    if not path.is_file():
        path = library_dir() / f"{s.lower()}.yaml"
    try:
        data = yaml_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError, RecursionError):
        return "serial"
    return "fivebar" if isinstance(data, Mapping) and data.get("kind") == "fivebar" else "serial"


def load_serial_robot(spec: str | os.PathLike[str], base_link: str | None = None,
               tip_link: str | None = None) -> Any:
    """Load a robot from a library name, a YAML robot file or a URDF file.

    Args:
        spec: built-in name (``puma560``; see ``kincal robots``) or a path.
        base_link, tip_link: for URDF files, the chain's first and last links
            (defaults: the URDF root and its single leaf).
    """
    s = str(spec)
    path = Path(s)
    if path.suffix.lower() == ".urdf":
        if not path.is_file():
            raise RobotFileError("no such URDF file", source=s)
        from kincal.robots.urdf import load_urdf

        return with_envelope_sidecar(load_urdf(path, base_link=base_link, tip_link=tip_link), path)
    if path.suffix.lower() in (".yaml", ".yml") or path.is_file():
        if not path.is_file():
            raise RobotFileError("no such robot file", source=s)
        return read_robot_yaml(path)
    lib = library_dir() / f"{s.lower()}.yaml"
    if lib.is_file():
        return read_robot_yaml(lib)
    raise RobotFileError(f"unknown robot {s!r}: not a file and not a built-in robot "
                         f"(built-in: {', '.join(library_names())})")


def envelope_sidecar(path: str | os.PathLike[str]) -> Path:
    """The file next to a URDF or UR kinematics file that carries its calibration
    envelope: ``NAME.envelope.yaml`` for ``NAME.urdf`` / ``NAME.yaml``."""
    p = Path(path)
    return p.with_name(p.stem + ".envelope.yaml")


def with_envelope_sidecar(robot: Robot, path: str | os.PathLike[str]) -> Robot:
    """``robot`` with ``meta["calibration"]`` (its envelope) from the sidecar next to
    ``path`` (:func:`write_envelope_sidecar`): the URDF or UR kinematics file ``robot``
    was read from; unchanged without one."""
    path = Path(path)
    side = envelope_sidecar(path)
    if not side.is_file():
        return robot
    text = read_text(side, "calibration envelope", RobotFileError)
    try:
        data = yaml_load(text)
    except yaml.YAMLError:
        raise RobotFileError(f"invalid YAML (the calibration envelope of {path.name})",
                             source=str(side)) from None
    r = FieldReader(str(side))
    top = r.mapping(data, "(top level)")
    meta = {**dict(robot.meta), "calibration_source": str(side)}
    if top.get("calibration") is not None or top.get("joint_model") is None:
        meta["calibration"] = dict(r.mapping(top.get("calibration"), "calibration"))
    if top.get("joint_model") is not None:    # read by kincal.workflow.carried_joint_model
        meta["joint_model"] = dict(r.mapping(top["joint_model"], "joint_model"))
    return dataclasses.replace(robot, meta=meta)


def write_envelope_sidecar(robot: Robot, path: str | os.PathLike[str]) -> Path | None:
    """Write the calibration envelope of ``robot`` (``meta["calibration"]``) next to the
    URDF or UR kinematics file ``path`` it was written to (:func:`envelope_sidecar`),
    atomically; None (nothing written) when the robot carries no envelope.  ROS tools
    and URDF readers never see the file; kincal reads it with the file it describes."""
    section = robot.meta.get("calibration")
    joints = robot.meta.get("joint_model")        # the calibrated joint model travels too
    if not (isinstance(section, Mapping) or isinstance(joints, Mapping)) or str(path) == "-":
        return None
    side = envelope_sidecar(path)
    doc: dict[str, Any] = {
        "describes": Path(path).name,
        "note": "the calibration envelope of the file it describes: kincal reads it with "
                "that file; keep the two together"}
    if isinstance(section, Mapping):
        doc["calibration"] = dict(section)
    if isinstance(joints, Mapping):
        doc["joint_model"] = dict(joints)
    text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=100)
    atomic_write_text(side, text)
    return side


# --------------------------------------------------------------------------- writing
def _fmt_frame(values: np.ndarray) -> dict[str, float]:
    """``{x, y, z, rx, ry, rz}`` (the file's key order) of frame values in
    :data:`~kincal.spatial.FRAME_FIELDS` order."""
    return {k: float(values[FRAME_FIELDS.index(k)]) for k in _FRAME_KEYS}


def _limits_out(lo: float, hi: float) -> list[float] | None:
    return None if not (math.isfinite(lo) and math.isfinite(hi)) else [float(lo), float(hi)]


def joint_units_of(robot: Robot) -> str | dict[str, str] | None:
    """What a robot file should say under ``joint_units``: ``"si"`` for URDF-derived
    robots and robots that declared it, the mapping a robot declared, else None."""
    declared = robot.meta.get("joint_units")
    if isinstance(declared, Mapping):
        return {str(k): str(v) for k, v in declared.items()}
    if declared == "si" or robot.meta.get("convention") == "urdf":
        return "si"
    return None


def robot_to_dict(robot: Robot, as_ets: bool = False) -> dict[str, Any]:
    """The YAML document of a robot, in SI units (m, rad), in its own convention.

    DH robots are written as DH tables (unless ``as_ets``); every other serial robot
    (URDF-derived included) as an explicit ``ets`` chain, so the file carries every
    parameter.  ``joint_units`` is written when :func:`joint_units_of` gives one.
    """
    conv = "ets" if as_ets else robot.meta.get("convention", "ets")
    doc: dict[str, Any] = {"name": robot.name}
    for key in ("vendor", "description", "source", "notes"):
        if key in robot.meta:
            doc[key] = robot.meta[key]
    doc["units"] = {"length": "m", "angle": "rad"}
    if robot.meta.get("tolerances"):
        doc["tolerances"] = dict(robot.meta["tolerances"])
    if isinstance(robot.meta.get("controller"), Mapping):
        doc["controller"] = dict(robot.meta["controller"])
    if isinstance(robot.meta.get("calibration"), Mapping):
        doc["calibration"] = dict(robot.meta["calibration"])
    if isinstance(robot.meta.get("joint_model"), Mapping):
        doc["joint_model"] = dict(robot.meta["joint_model"])
    ju = joint_units_of(robot)
    if ju is not None:
        doc["joint_units"] = ju
    if conv in ("standard_dh", "modified_dh", "hayati"):
        doc["convention"] = conv
        doc["base"] = _fmt_frame(robot.frame_parameters("base"))
        doc["tool"] = _fmt_frame(robot.frame_parameters("tool"))
        rows = []
        for L in dh_links(robot):
            row: dict[str, Any] = {"name": L.name, "type": L.joint, "a": L.a, "d": L.d,
                                   "alpha": L.alpha, "theta_offset": L.theta_offset}
            if L.beta is not None:
                row["beta"] = L.beta
            lim = _limits_out(L.lower, L.upper)
            if lim:
                row["limits"] = lim
            rows.append(row)
        doc["joints"] = rows
        return doc
    doc["convention"] = "ets"
    doc["base"] = _fmt_frame(robot.frame_parameters("base"))
    doc["tool"] = _fmt_frame(robot.frame_parameters("tool"))
    doc["joints"] = []
    for j in robot.joints:
        row = {"name": j.name, "type": j.kind}
        lim = _limits_out(j.lower, j.upper)
        if lim:
            row["limits"] = lim
        doc["joints"].append(row)
    chain = []
    for et in robot.ets:
        pname = robot.param_names[et.param] if et.param >= 0 else None
        if pname and (pname.startswith("base.") or pname.startswith("tool.")):
            continue
        row = {"transform": et.kind, "name": pname,
               "value": float(robot.param_values[et.param]) if et.param >= 0 else et.constant}
        if et.param >= 0:
            row["role"] = robot.param_roles[et.param]
        if et.joint >= 0:
            row["joint"] = robot.joints[et.joint].name
            if et.scale != 1.0:
                row["scale"] = et.scale
        chain.append(row)
    doc["chain"] = chain
    return doc


def robot_yaml_text(robot: Robot, as_ets: bool = False) -> str:
    """The YAML robot file of ``robot`` (SI units; see :func:`robot_to_dict`), as text."""
    return yaml.safe_dump(robot_to_dict(robot, as_ets), sort_keys=False,
                          default_flow_style=None, width=100)


def write_robot_yaml(robot: Robot, path: str | os.PathLike[str], as_ets: bool = False) -> None:
    """Write ``robot`` as a YAML robot file (SI units), atomically (``-``: stdout).

    ``as_ets`` writes a DH robot as an explicit elementary-transform chain.
    """
    atomic_write_text(path, robot_yaml_text(robot, as_ets))
