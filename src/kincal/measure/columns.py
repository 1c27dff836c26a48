"""Column-name maps: a file's columns read under the names kincal knows.

A recorder names its columns its own way (a ROS driver ``shoulder_pan_joint``, a tracker
export ``measurement_x``); the file is read as it is, its columns renamed on reading:

* **ROS joint names of the built-in robots** are recognised without being asked: the UR
  robots' ``shoulder_pan_joint`` ... ``wrist_3_joint`` (the UR driver's
  ``joint_states``), the Panda's ``panda_joint1`` ... ``panda_joint7``, the KUKA KR 6's
  ``joint_a1`` ... ``joint_a6`` and the ABB IRB 120's ``joint_1`` ... ``joint_6``
  (ROS-Industrial).  Their values are rad (ROS REP 103) in the vendor's joint zeros and
  directions, which the built-in models use; a unit suffix on the column
  (``shoulder_pan_joint_deg``) still wins.  Only when *every* joint of the robot has
  its ROS column and none has its own name.
* **A joint-name map** ``{file column: robot joint}``: tag ``joint_names=COL=JOINT,...``
  (the CLI's ``--joint-names``, a setup file's ``joint_names:``).  ``JOINT`` may carry a
  unit suffix (``J1=q1_deg``); a bare one takes its unit from ``--units`` on the file's
  column name, or from the robot file as usual.
* **A column map** ``{file column: kincal column}``: tag ``columns=COL=NAME,...`` (a
  setup file's ``columns:``), for observation columns (``measurement_x: x_mm``).

A map naming a column the file does not have, or a joint the robot does not have, is
one error line listing what there is.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from kincal.errors import MeasurementFileError
from kincal.units import UNITS

__all__ = ["ROS_JOINT_NAMES", "ColumnMap", "map_columns", "parse_map", "format_map",
           "ros_names", "missing_joints_message"]

_UR = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")

#: Built-in robot -> {ROS joint name: the robot's joint}.
ROS_JOINT_NAMES: dict[str, dict[str, str]] = {
    **{ur: {f"{j}_joint": j for j in _UR}
       for ur in ("ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20",
                  "ur30")},
    "panda": {f"panda_joint{i}": f"q{i}" for i in range(1, 8)},
    "kr6": {f"joint_a{i}": f"A{i}" for i in range(1, 7)},
    "irb120": {f"joint_{i}": f"rax_{i}" for i in range(1, 7)},
}

#: The tags that carry maps (a map's text: ``COL=NAME,COL=NAME``).
MAP_TAGS = ("joint_names", "columns")

Fail = Callable[..., MeasurementFileError]


@dataclass
class ColumnMap:
    """The result of :func:`map_columns`.

    Attributes:
        names: the header's names after renaming (same length and order).
        renamed: ``{file column: new name}`` of the renamed columns.
        units: the ``--units`` map with keys naming a renamed column moved to its new name.
        ignore: the ``--ignore`` entries likewise.
        notes: one line per kind of renaming, for the command to print.
    """

    names: list[str]
    renamed: dict[str, str] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    ignore: tuple[str, ...] = ()
    notes: list[str] = field(default_factory=list)


def key_value_pairs(text: str, what: str, form: str, example: str
                    ) -> Iterator[tuple[str, str, str]]:
    """The ``KEY=VALUE`` entries of comma-separated ``text`` as ``(key, value, entry)``,
    blank entries skipped; an entry without ``=`` is one error line naming ``what`` and
    the expected ``form`` (``example`` shows one)."""
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        if "=" not in part:
            raise MeasurementFileError(f"{what}: {part!r} is not {form} (e.g. {example})")
        k, v = (s.strip() for s in part.split("=", 1))
        yield k, v, part


def parse_map(text: str, what: str = "joint_names") -> dict[str, str]:
    """``"a=b, c=d"`` -> ``{"a": "b", "c": "d"}``; one error line for a bad entry."""
    out: dict[str, str] = {}
    for k, v, part in key_value_pairs(text, what, "FILE_COLUMN=NAME",
                                      "shoulder_pan_joint=shoulder_pan"):
        if not k or not v:
            raise MeasurementFileError(f"{what}: {part!r} has an empty name")
        if k in out:
            raise MeasurementFileError(f"{what}: column {k!r} is mapped twice")
        out[k] = v
    return out


def format_map(mapping: Mapping[str, str]) -> str:
    """The tag text of a map (inverse of :func:`parse_map`)."""
    for k, v in mapping.items():
        for s in (str(k), str(v)):
            if any(c in s for c in ",=;"):
                raise MeasurementFileError(f"column name {s!r}: a mapped name may not "
                                           "hold ',' '=' or ';'")
    return ",".join(f"{k}={v}" for k, v in mapping.items())


def ros_names(robot: Any) -> dict[str, str]:
    """``{ROS joint name: joint}`` of a built-in robot (``{}`` for any other robot)."""
    if robot is None or (getattr(robot, "meta", {}) or {}).get("convention") == "urdf":
        return {}
    table = ROS_JOINT_NAMES.get(str(getattr(robot, "name", "")), {})
    joints = {j.name for j in robot.joints}
    return table if set(table.values()) == joints else {}


def _split(name: str) -> tuple[str, str | None]:
    if "_" in name:
        base, suffix = name.rsplit("_", 1)
        if suffix in UNITS and base:
            return base, suffix
    return name, None


def _joint_map(names: Sequence[str], tags: Mapping[str, str], robot: Any,
               fail: Fail) -> tuple[dict[str, str], str]:
    """``{file column: new column name}`` for the joints, and its note."""
    if robot is None:                  # a header read without its robot: joints stay
        return {}, ""
    jnames = [j.name for j in robot.joints]
    given = tags.get("joint_names")
    if given and given.strip().lower() == "ros":
        if not ros_names(robot):
            known = ", ".join(sorted(ROS_JOINT_NAMES))
            raise fail(f"joint_names ros: robot {robot.name!r} has no "
                       f"known ROS joint names (built-in robots with them: {known}); give "
                       "the map FILE_COLUMN=JOINT,...")
        missing = [r for r in ros_names(robot)
                   if r not in names and r not in {_split(n)[0] for n in names}]
        if missing:
            raise fail(f"joint_names ros: the file has no column {missing[0]!r} (columns: "
                       f"{', '.join(names)})")
        given = None
    if given:
        mapping = parse_map(given)
        out = {}
        for col, target in mapping.items():
            if col not in names:
                raise fail(f"joint_names: the file has no column {col!r} (columns: "
                           f"{', '.join(names)})")
            joint, unit = _split(target)
            if joint not in jnames and target not in jnames:
                raise fail(f"joint_names: robot {robot.name!r} has no joint {target!r} "
                           f"(joints: {', '.join(jnames)})")
            out[col] = target
        return out, _mapped("joint columns mapped", out)
    ros = ros_names(robot)
    if not ros:
        return {}, ""
    bases = {_split(n)[0]: n for n in names}
    bases.update({n: n for n in names})       # a whole name first: joint_1 is no "_1" unit
    if any(j in bases for j in jnames) or not all(r in bases for r in ros):
        return {}, ""
    out = {}
    for r, joint in ros.items():
        col = bases[r]
        unit = "rad" if col == r else _split(col)[1]
        out[col] = f"{joint}_{unit}"
    return out, (f"ROS joint names read as the joints of robot {robot.name!r} "
                 f"({next(iter(ros))} -> {ros[next(iter(ros))]} ...; rad unless the "
                 "column says its unit)")


def map_columns(names: Sequence[str], tags: Mapping[str, str], robot: Any,
                units: Mapping[str, str], ignore: Sequence[str], fail: Fail) -> ColumnMap:
    """Rename a header's columns by the file's maps (see the module text).

    Args:
        names: the header's column names as written.
        tags: the file's tags (maps in ``joint_names`` / ``columns``).
        robot: the robot whose joints the file names (None: no joint renaming).
        units, ignore: the reader's ``--units`` / ``--ignore``, keyed on the file's names.
        fail: the reader's one-line error for the header line.
    """
    renamed: dict[str, str] = {}
    notes: list[str] = []
    if tags.get("columns"):
        for col, new in parse_map(tags["columns"], "columns").items():
            if col not in names:
                raise fail(f"columns: the file has no column {col!r} (columns: "
                           f"{', '.join(names)})")
            renamed[col] = new
        notes.append(_mapped("columns mapped", renamed))
    jmap, note = _joint_map(names, tags, robot, fail)
    for col, new in jmap.items():
        if col in renamed:
            raise fail(f"column {col!r} is in both columns: and joint_names:")
        renamed[col] = new
    if note:
        notes.append(note)
    out = [renamed.get(n, n) for n in names]
    new_units: dict[str, str] = {}
    for k, v in units.items():
        for key in _moved(k, names, renamed):
            new_units.setdefault(key, v)
    new_ignore = tuple(key for p in ignore for key in _moved(p, names, renamed))
    return ColumnMap(out, renamed, new_units, new_ignore, notes)


def _moved(pattern: str, names: Sequence[str], renamed: Mapping[str, str]) -> list[str]:
    """A ``--units`` / ``--ignore`` key after renaming: the new names of the renamed
    columns it matches, and itself when it matches a column that keeps its name (or
    none at all, so that the reader's own message names it)."""
    rx = re.compile("".join(".*" if c == "*" else "." if c == "?" else re.escape(c)
                            for c in pattern) + r"\Z")
    hit = [n for n in names if rx.match(n)]
    out = [renamed[n] for n in hit if n in renamed]
    if not out or any(n not in renamed for n in hit):
        out.append(pattern)
    return out


def missing_joints_message(robot: Any, missing: str, have: Sequence[str],
                           names: Sequence[str]) -> str:
    """The error for a file without a column for joint ``missing``: the columns found,
    the names expected, and how to map them (with the ROS names of a built-in robot)."""
    jnames = [j.name for j in robot.joints]
    msg = (f"no column for joint {missing!r}: robot {robot.name!r} has {len(jnames)} joints "
           f"({', '.join(jnames)}), the file has {len(have)} joint columns"
           f" ({', '.join(have) or 'none'}); its columns are: {', '.join(names)}. ")
    ros = ROS_JOINT_NAMES.get(str(robot.name))
    example = (f"{next(iter(ros))}={ros[next(iter(ros))]}" if ros
               else f"{names[0]}={jnames[0]}")
    return msg + (f"Name the columns after the joints, or map them: --joint-names "
                  f"'{example},...' (joint_names: in a setup file)")


def _mapped(what: str, renamed: Mapping[str, str], shown: int = 3) -> str:
    """``"columns mapped: a -> b, c -> d ... (12 in all)"``: one short line."""
    items = [f"{k} -> {v}" for k, v in renamed.items()]
    more = f" ... ({len(items)} in all)" if len(items) > shown else ""
    return f"{what}: {', '.join(items[:shown])}{more}"
