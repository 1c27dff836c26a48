"""Measurement CSV files with explicit units: reading and writing.

A measurement file is a CSV table, one measurement (robot configuration) per row::

    # kincal measurements: instrument=position; name=tracker
    # any further comment lines
    q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,sigma_mm
    10.5,-20.25,...

Rules (every violation is one :class:`~kincal.errors.MeasurementFileError` line
naming the file, the line and the column; nothing is guessed):

* **Units in every header.**  A column is ``BASE_UNIT`` with ``UNIT`` one of
  :data:`kincal.units.UNITS` (``m mm um cm``, ``rad deg mrad urad arcsec arcmin``,
  ``s ms``, ``px``, ``1``).
  A column without a unit suffix needs its unit from the user (``units``: the CLI's
  ``--units x1=m,arm_1_joint=rad``; keys are column names or ``*``/``?`` patterns)
  or, for joint columns only, from the robot file: a URDF fixes joint units to
  rad / m, so bare URDF joint names (``arm_3_joint``) are read in rad (m for
  prismatic joints); so does a robot whose ``meta["joint_units"]`` says ``"si"``.
  A unit must have the right dimension (an angle for a revolute joint or ``rx``, a
  length for a prismatic joint or ``x``).
* **Joint columns** are named exactly as the robot's joints (``q1_deg`` for a DH
  robot, ``arm_3_joint`` for a URDF robot, ``S_rad`` ...); every joint must appear
  once.
* **Observation columns** are the instrument's (:class:`Field` patterns): position
  ``x y z`` or ``x1 y1 z1 x2 ...``, pose ``x y z rx ry rz`` (roll-pitch-yaw,
  ``R = Rz(rz) Ry(ry) Rx(rx)``), per-row standard deviations ``sigma`` (length)
  and ``sigma_rot`` (angle).
* **Other columns.**  A column that is neither a joint nor an observation of the
  instrument is *ignored only if it does not look like one*: names such as
  ``q7``, ``x5``, ``rz2``, ``sigma2``, ``joint3`` or a near-miss of a joint name
  (``arm_8_joint``, ``Arm_3_joint``) are errors (a wrong joint count or a typo must
  not be dropped silently).  List such a column with ``ignore`` (CLI ``--ignore
  'x2,y2,z2'``, patterns allowed) to drop it on purpose.  Bookkeeping columns
  (``pose_id``, ``shipped_row``, ``t_start_robot``, ``marker_std_mm``) are
  ignored, and the reader reports their names in :attr:`MeasurementTable.ignored`
  (the CLI prints them).
* **Values** must be finite numbers: text, empty cells, ``nan`` and ``inf`` are
  errors naming the line and the column; every row has as many fields as the
  header.  Blank lines and lines starting with ``#`` are skipped.

Everything is converted to SI (m, rad) at the border.  Writers write whatever
units they are asked to (default SI) through a temporary file and a rename.
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import MeasurementFileError
from kincal.io import atomic_write_text, read_text
from kincal.measure.columns import key_value_pairs, map_columns, missing_joints_message
from kincal.measure.dialect import Dialect, normalise, sniff
from kincal.robots.hold import held_joints
from kincal.units import DIMENSIONS, MAX_SI, UNITS

Array = NDArray[np.float64]

#: How far [rad / m] a held joint's column may read from its held value.
HELD_TOLERANCE = 1e-4

#: First-line tag of a kincal measurement file.
TAG_PREFIX = "# kincal measurements:"

#: Names that look like joint values or observations: never ignored silently.
LOOKS_MEASURED = re.compile(
    r"(q|j|joint|theta|[xyz]|r[xyz]|roll|pitch|yaw|sigma|sigma_rot|range|distance"
    r"|azimuth|elevation|bearing|[uv])\d*", re.IGNORECASE)


@dataclass(frozen=True)
class Field:
    """An observation column family of an instrument.

    Attributes:
        pattern: regular expression full-matched against a column's base name
            (the name without its unit suffix), e.g. ``[xyz]\\d+``.
        dimension: ``"length"``, ``"angle"``, ``"pixel"`` or ``"dimensionless"``.
        description: for error messages and documentation.
    """

    pattern: str
    dimension: str
    description: str = ""

    def matches(self, base: str) -> bool:
        return re.fullmatch(self.pattern, base) is not None


@dataclass
class MeasurementTable:
    """A parsed measurement file, in SI units.

    Attributes:
        path: the file.
        tags: the first-line tags (``instrument``, ``name`` ...), ``{}`` when absent.
        q: (N, n) joint values [rad / m] in the robot's joint order (n = 0 when the
            file has no joint columns, e.g. a targets file).
        values: observation columns by base name (``"x"``, ``"x2"``, ``"rz"``,
            ``"sigma"``), each (N,) in SI units.
        units: the unit each used column was read in (``{"x": "mm", "q1": "deg"}``).
        lines: (N,) file line number of every row (1-based), for messages.
        ignored: names of the columns that were not read.
        columns: observation base name -> column header as written in the file.
        notes: how the file was read when it differs from kincal's own spelling (its
            CSV dialect, renamed columns), one line each, for the command to print.
    """

    path: str
    tags: dict[str, str]
    q: Array
    values: dict[str, Array]
    units: dict[str, str]
    lines: NDArray[np.intp]
    ignored: list[str] = field(default_factory=list)
    columns: dict[str, str] = field(default_factory=dict)
    header_line: int = 1
    notes: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.lines.size)

    def has(self, *bases: str) -> bool:
        return all(b in self.values for b in bases)

    def error(self, message: str, line: int | None = None) -> MeasurementFileError:
        """A one-line error naming the file and ``line`` (default: the header line)."""
        line = self.header_line if line is None else line
        return MeasurementFileError(f"line {line}: {message}", source=self.path)


# --------------------------------------------------------------------------- helpers
def split_unit(name: str) -> tuple[str, str | None]:
    """``"x1_mm" -> ("x1", "mm")``; ``"arm_3_joint" -> ("arm_3_joint", None)``."""
    if "_" in name:
        base, suffix = name.rsplit("_", 1)
        if suffix in UNITS and base:
            return base, suffix
    return name, None


def glob_regex(pattern: str) -> re.Pattern[str]:
    """``*`` and ``?`` wildcards; every other character (``[`` included) is literal."""
    body = "".join(".*" if c == "*" else "." if c == "?" else re.escape(c) for c in pattern)
    return re.compile(body + r"\Z")


def parse_units_option(text: str | None, option: str = "--units") -> dict[str, str]:
    """Parse ``"x1=m,y1=m,arm_1_joint=rad"`` into ``{column or pattern: unit}``."""
    out: dict[str, str] = {}
    if not text:
        return out
    for k, v, _ in key_value_pairs(text, f"option {option}", "COLUMN=UNIT",
                                   "x1=m,arm_1_joint=rad"):
        if v not in UNITS:
            raise MeasurementFileError(f"option {option}: unknown unit {v!r} for {k!r} "
                                       f"(known: {', '.join(UNITS)})")
        out[k] = v
    return out


def parse_list_option(text: str | Sequence[str] | None) -> list[str]:
    """``"a,b, c"`` (or a list of such strings) -> ``["a", "b", "c"]``."""
    if not text:
        return []
    items = [text] if isinstance(text, str) else list(text)
    return [p.strip() for s in items for p in s.split(",") if p.strip()]


def _robot_joint_units(robot: Any) -> dict[str, str]:
    """Units a robot file fixes for bare joint columns.

    A URDF fixes rad / m (the URDF standard); a robot whose ``meta["joint_units"]`` is
    ``"si"`` or a ``{joint: unit}`` mapping declares them.  Otherwise none.
    """
    if robot is None:
        return {}
    meta = getattr(robot, "meta", {}) or {}
    declared = meta.get("joint_units")
    if isinstance(declared, Mapping):
        return {str(k): str(v) for k, v in declared.items()}
    if declared == "si" or meta.get("convention") == "urdf":
        kinds = {j.name: j.kind for j in robot.joints}
        kinds.update(dict(meta.get("held_joint_kinds") or {}))
        return {n: "rad" if k == "revolute" else "m" for n, k in kinds.items()}
    return {}


def _read_lines(path: str | os.PathLike[str]) -> list[str]:
    src = str(path)
    text = read_text(path, "measurement file", MeasurementFileError)
    if not text.strip():
        raise MeasurementFileError("line 1: the file is empty", source=src)
    return text.splitlines()


_TAG_OVERRIDES: ContextVar[Mapping[str, dict[str, str]]] = ContextVar(
    "kincal_tag_overrides", default=MappingProxyType({}))


def _path_key(path: str | os.PathLike[str]) -> str:
    return os.path.realpath(os.fspath(path))


@contextmanager
def tag_overrides(path: str | os.PathLike[str], tags: Mapping[str, str]) -> Iterator[None]:
    """Read ``path`` as if its tag line also said ``tags`` (they win over the file's).

    How a setup file or ``--instrument`` / ``--option`` give a file's instrument and its
    options (``instrument=two-socket``, ``length_mm=50``) without editing the file.
    """
    current = dict(_TAG_OVERRIDES.get())
    key = _path_key(path)
    current[key] = {**current.get(key, {}), **{str(k): str(v) for k, v in tags.items()}}
    token = _TAG_OVERRIDES.set(current)
    try:
        yield
    finally:
        _TAG_OVERRIDES.reset(token)


def file_tags(path: str | os.PathLike[str], first_line: str) -> dict[str, str]:
    """The tags of ``path``: its tag line's, updated by any :func:`tag_overrides`."""
    tags = parse_tags(first_line)
    extra = _TAG_OVERRIDES.get().get(_path_key(path))
    return {**tags, **extra} if extra else tags


def has_tag_line(path: str | os.PathLike[str]) -> bool:
    """True when the file's first line is a ``# kincal measurements:`` tag line."""
    return _read_lines(path)[0].startswith(TAG_PREFIX)


def parse_tags(first_line: str) -> dict[str, str]:
    """Tags of a ``# kincal measurements: instrument=NAME; name=BLOCK`` line, else ``{}``."""
    if not first_line.startswith(TAG_PREFIX):
        return {}
    tags: dict[str, str] = {}
    for part in first_line[len(TAG_PREFIX):].split(";"):
        if "=" in part:
            k, v = part.split("=", 1)
            tags[k.strip()] = v.strip()
    return tags


def tag_quantities(tags: Mapping[str, str], src: str) -> dict[str, tuple[float, str]]:
    """Numeric tags with a unit suffix in SI: ``{"length_mm": "300"} -> {"length": (0.3,
    "length")}`` (other tags are skipped); a value that is not a finite number is an
    error naming line 1."""
    out: dict[str, tuple[float, str]] = {}
    for key, text in tags.items():
        base, unit = split_unit(key)
        if unit is None:
            continue
        try:
            v = float(text)
        except ValueError:
            raise MeasurementFileError(f"line 1: {key}={text!r} is not a number",
                                       source=src) from None
        if not math.isfinite(v):
            raise MeasurementFileError(f"line 1: {key} is not finite", source=src)
        out[base] = (v * UNITS[unit][1], UNITS[unit][0])
    return out


def tag_quantity(values: Mapping[str, tuple[float, str]], key: str, dim: str, src: str,
                 default: float | None = None) -> float:
    """The SI value of tag ``key`` from :func:`tag_quantities`, checking its dimension;
    ``default`` when absent (None: an error asking for it)."""
    if key not in values:
        if default is None:
            raise MeasurementFileError(f"line 1: missing tag {key}_<unit> (e.g. {key}_"
                                       f"{'mm' if dim == 'length' else 'deg'}=...)",
                                       source=src)
        return default
    v, d = values[key]
    if d != dim:
        raise MeasurementFileError(f"line 1: tag {key} needs a{'n' if dim[0] in 'aeiou' else ''}"
                                   f" {dim} unit", source=src)
    return v


def read_header(path: str | os.PathLike[str]) -> tuple[dict[str, str], list[str], int]:
    """The tags, the header's column names and the header's line number (1-based)."""
    lines = _read_lines(path)
    tags = file_tags(path, lines[0])
    body = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and
            not ln.lstrip().startswith("#")]
    if body:
        header_line, body, _ = _sniffed(body, str(path))
        names = [c.strip() for c in next(csv.reader([body[0][1]]))]

        def fail(msg: str) -> MeasurementFileError:
            return MeasurementFileError(f"line {header_line}: {msg}", source=str(path))

        return tags, map_columns(names, tags, None, {}, (), fail).names, header_line
    raise MeasurementFileError(f"line {len(lines)}: no header line (only comments)",
                               source=str(path))


# --------------------------------------------------------------------------- reading
#: ``fail(message, line=header line)``: the one-line error of the file being read.
Fail = Callable[..., MeasurementFileError]

#: A column read: ``(column index, base name, unit, role)``, role ``joint``, ``held`` or ``obs``.
UsedColumn = tuple[int, str, str, str]


@dataclass(frozen=True)
class _JointColumns:
    """What a table's joint columns must be: the robot's joints and held joints."""

    names: list[str]                    # the robot's joint names (empty: no joint columns)
    kind: dict[str, str]                # joint or held joint -> revolute / prismatic
    held: dict[str, float]              # held joint -> its value [SI]
    units: dict[str, str]               # the robot file's joint units
    lower: dict[str, str]               # lower-case name -> name (for suggestions)

    @classmethod
    def of(cls, robot: Any, joints: bool) -> _JointColumns:
        jnames = [j.name for j in robot.joints] if joints and robot is not None else []
        jkind = {j.name: j.kind for j in robot.joints} if jnames else {}
        held = held_joints(robot) if jnames else {}
        jkind.update(dict(robot.meta.get("held_joint_kinds") or {}) if held else {})
        robot_units = _robot_joint_units(robot) if jnames else {}
        return cls(jnames, jkind, held, robot_units, {n.lower(): n for n in jnames})


def read_table(path: str | os.PathLike[str], robot: Any, fields: Sequence[Field],
               units: Mapping[str, str] | None = None, ignore: Sequence[str] = (),
               joints: bool = True) -> MeasurementTable:
    """Read a measurement CSV into SI arrays, following the rules of this module.

    Args:
        path: the CSV file.
        robot: the robot the joint columns belong to (its ``joints``: name, kind).
        fields: the instrument's observation columns.
        units: ``{column or pattern: unit}`` for columns whose header has no unit.
        ignore: column names or ``*``/``?`` patterns to drop on purpose.
        joints: False for files without joint columns (e.g. target poses).

    Raises:
        MeasurementFileError: one line naming the file, line and column.
    """
    src = str(path)
    units = dict(units or {})
    lines = _read_lines(path)
    tags = file_tags(path, lines[0])
    body = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip() and
            not ln.lstrip().startswith("#")]
    if not body:
        raise MeasurementFileError(f"line {len(lines)}: no header line (only comments)",
                                   source=src)
    header_line, body, dialect = _sniffed(body, src)
    header_text = body[0][1]
    names = [c.strip() for c in next(csv.reader([header_text]))]

    def fail(msg: str, line: int = header_line) -> MeasurementFileError:
        return MeasurementFileError(f"line {line}: {msg}", source=src)

    cmap = map_columns(names, tags, robot if joints else None, units, ignore, fail)
    file_names, names, units = names, cmap.names, cmap.units
    ignore_rx, unit_rx = _check_header(names, cmap.ignore, units, fail)
    jc = _JointColumns.of(robot, joints)
    used, ignored, bases = _sort_columns(names, fields, ignore_rx, unit_rx, jc, fail)
    if jc.names:
        missing = [j for j in jc.names if j not in bases]
        if missing:
            have = [b for _, b, _, r in used if r == "joint"]
            raise fail(missing_joints_message(robot, missing[0], have, file_names))

    data_rows = body[1:]
    if not data_rows:
        raise fail("no data rows after the header", line=header_line)
    arr, cells, linenos = _read_numbers(data_rows, names, used, fail)
    pos = {b: k for k, (_, b, _, _) in enumerate(used)}
    q = (np.stack([arr[:, pos[j]] for j in jc.names], axis=1) if jc.names
         else np.zeros((len(data_rows), 0)))
    values = {b: arr[:, k] for k, (_, b, _, r) in enumerate(used) if r == "obs"}
    col_names = {b: names[c] for c, b, _, r in used if r == "obs"}
    _check_held(arr, cells, linenos, names, used, jc.held, ignored, fail)
    notes = ([dialect.note] if dialect.note else []) + cmap.notes
    return MeasurementTable(src, tags, q, values, {b: u for _, b, u, r in used if r != "held"},
                            linenos, ignored, col_names, header_line, notes)


def _sniffed(body: list[tuple[int, str]], src: str
             ) -> tuple[int, list[tuple[int, str]], Dialect]:
    """The header line, the body lines in kincal's dialect and the file's dialect
    (:mod:`kincal.measure.dialect`)."""
    header_line = body[0][0]
    dialect = sniff(body[0][1], [ln for _, ln in body[1:]], src, header_line,
                    [i for i, _ in body[1:]])
    text = normalise([ln for _, ln in body], dialect)
    return header_line, [(i, t) for (i, _), t in zip(body, text, strict=True)], dialect


def _check_header(names: Sequence[str], ignore: Sequence[str], units: Mapping[str, str],
                  fail: Fail) -> tuple[list[tuple[str, re.Pattern[str]]],
                                       list[tuple[str, str, re.Pattern[str]]]]:
    """Column names unique and non-empty; every ``--ignore`` pattern and ``--units`` key
    matches a column (a typo must not pass unnoticed).  Returns the compiled patterns."""
    seen: dict[str, int] = {}
    for c, name in enumerate(names, start=1):
        if not name:
            raise fail(f"column {c} has an empty name")
        if name in seen:
            raise fail(f"column {c} ({name}) repeats column {seen[name]}")
        seen[name] = c
    ignore_rx = [(p, glob_regex(p)) for p in ignore]
    for p, rx in ignore_rx:
        if not any(rx.match(n) for n in names):
            raise fail(f"--ignore {p!r} matches no column (columns: {', '.join(names)})")
    unit_rx = [(k, v, glob_regex(k)) for k, v in units.items()]
    for k, _, rx in unit_rx:
        if not any(rx.match(n) for n in names):
            raise fail(f"--units {k!r} matches no column (columns: {', '.join(names)})")
    return ignore_rx, unit_rx


def _sort_columns(names: Sequence[str], fields: Sequence[Field],
                  ignore_rx: Sequence[tuple[str, re.Pattern[str]]],
                  unit_rx: Sequence[tuple[str, str, re.Pattern[str]]], jc: _JointColumns,
                  fail: Fail) -> tuple[list[UsedColumn], list[str], dict[str, int]]:
    """Each column a joint, a held joint, an observation (with its unit) or ignored.

    Returns the columns read, the names ignored and ``{base name: column number}``.
    """
    used: list[UsedColumn] = []
    no_unit: list[tuple[int, str, str, str]] = []   # (column, name, base, dimension)
    ignored: list[str] = []
    bases: dict[str, int] = {}
    jnames, held = jc.names, jc.held
    for c, name in enumerate(names):
        col = c + 1
        if any(rx.match(name) for _, rx in ignore_rx):
            ignored.append(name)
            continue
        base, unit = split_unit(name)
        if base not in jnames and name in jnames:       # a joint whose name ends in _m ...
            base, unit = name, None
        if base not in held and name in held:
            base, unit = name, None
        if base in jnames or base in held:
            role = "joint" if base in jnames else "held"
            want = "angle" if jc.kind[base] == "revolute" else "length"
        else:
            fld = next((f for f in fields if f.matches(base)), None)
            if fld is None:
                if unit is None and "_" in name:
                    pre, suf = name.rsplit("_", 1)
                    if _looks_measured(pre, jnames) and suf not in UNITS:
                        raise fail(f"column {col} ({name}): unknown unit {suf!r} "
                                   f"(known: {', '.join(UNITS)})")
                if _looks_measured(base, jnames):
                    raise fail(f"column {col} ({name}) " + _unexpected(base, jnames, jc.lower,
                                                                      fields))
                ignored.append(name)
                continue
            role, want = "obs", fld.dimension
        if base in bases:
            raise fail(f"column {col} ({name}) repeats {base!r} (column {bases[base]})")
        bases[base] = col
        given = next((v for k, v, rx in unit_rx if k == name), None)
        if unit is not None and given is not None and given != unit:
            raise fail(f"column {col} ({name}) says its unit is {unit}; --units says {given}")
        if given is None and unit is None:     # patterns only fill in missing units
            given = next((v for _, v, rx in unit_rx if rx.match(name)), None)
        unit = unit or given
        if unit is None and role in ("joint", "held"):
            unit = jc.units.get(base)
        if unit is None:
            no_unit.append((col, name, base, want))
            continue
        if UNITS[unit][0] != want:
            raise fail(f"column {col} ({name}): unit {unit} is {_a(UNITS[unit][0])}, "
                       f"expected {_a(want)}")
        used.append((c, base, unit, role))
    if no_unit:
        raise fail(_no_unit_message(no_unit))
    return used, ignored, bases


def _read_numbers(data_rows: Sequence[tuple[int, str]], names: Sequence[str],
                  used: Sequence[UsedColumn], fail: Fail
                  ) -> tuple[Array, list[list[str]], NDArray[np.intp]]:
    """The used columns of the data rows as SI numbers (rows, columns), the cells as
    written, and the file line of each row; every cell finite and within :data:`MAX_SI`."""
    rows = list(csv.reader([ln for _, ln in data_rows]))
    linenos = np.array([ln for ln, _ in data_rows], dtype=np.intp)
    width = len(names)
    for (ln, _), r in zip(data_rows, rows, strict=True):
        if len(r) != width:
            raise fail(f"{len(r)} values, but the header has {width} columns", line=ln)
    idx = [c for c, _, _, _ in used]
    cells = [[r[c] for c in idx] for r in rows]
    try:
        arr = np.array(cells, dtype=float).reshape(len(rows), len(idx))
    except ValueError:
        arr = None
    if arr is None:
        for (ln, _), r in zip(data_rows, cells, strict=True):
            for col, s in enumerate(r):
                try:
                    float(s)
                except ValueError:
                    c = idx[col]
                    what = "is empty" if not s.strip() else f"{s.strip()!r} is not a number"
                    raise fail(f"column {c + 1} ({names[c]}): {what}", line=ln) from None
        raise fail("unreadable numbers")  # pragma: no cover
    bad = ~np.isfinite(arr)
    if bad.any():
        i, k = np.argwhere(bad)[0]
        c = idx[k]
        raise fail(f"column {c + 1} ({names[c]}): {cells[i][k].strip()!r} is not a finite "
                   "number", line=int(linenos[i]))
    scale = np.array([UNITS[u][1] for _, _, u, _ in used])
    arr = arr * scale
    big = np.abs(arr) > MAX_SI
    if big.any():
        i, k = np.argwhere(big)[0]
        c = idx[k]
        raise fail(f"column {c + 1} ({names[c]}): {cells[i][k].strip()} is out of any "
                   f"robot's range (more than {MAX_SI:g} {DIMENSIONS[UNITS[used[k][2]][0]]})",
                   line=int(linenos[i]))
    return arr, cells, linenos


def _check_held(arr: Array, cells: Sequence[Sequence[str]], linenos: NDArray[np.intp],
                names: Sequence[str], used: Sequence[UsedColumn], held: Mapping[str, float],
                ignored: list[str], fail: Fail) -> None:
    """A held joint's column must read its held value (within :data:`HELD_TOLERANCE`) on
    every row; its column is then listed in ``ignored``."""
    for col, (c, b, u, role) in enumerate(used):
        if role != "held":
            continue
        off = np.abs(arr[:, col] - held[b])
        if np.max(off) > HELD_TOLERANCE:
            i = int(np.flatnonzero(off > HELD_TOLERANCE)[0])
            raise fail(f"column {c + 1} ({names[c]}): joint {b} is held at "
                       f"{held[b] / UNITS[u][1]:.6g} {u}, but this row reads "
                       f"{cells[i][col].strip()} {u}: it moved (remove it from hold)",
                       line=int(linenos[i]))
        ignored.append(f"{names[c]} (held joint)")


def _no_unit_message(cols: Sequence[tuple[int, str, str, str]]) -> str:
    """One message for every column without a unit, with the ``--units`` that fixes it."""
    example = {"angle": "deg", "length": "mm", "pixel": "px"}
    first = cols[0]
    what = (f"column {first[0]} ({first[1]}) has no unit" if len(cols) == 1 else
            f"{len(cols)} columns have no unit: " + ", ".join(n for _, n, _, _ in cols))
    pats: dict[str, str] = {}
    for _, name, _, want in cols:
        pat = re.sub(r"\d+$", "?", name) if sum(
            re.sub(r"\d+$", "?", n) == re.sub(r"\d+$", "?", name) for _, n, _, _ in cols) > 1 \
            else name
        pats.setdefault(pat, "UNIT" if want not in example else
                        f"{example[want] if want != 'length' else 'm'}")
    fix = ",".join(f"{k}={v}" for k, v in pats.items())
    return (f"{what}: name them with their unit (like {first[2]}_"
            f"{example.get(first[3], 'mm')}) or pass --units '{fix}' (with the real units)")


def _a(word: str) -> str:
    return ("an " if word[0] in "aeiou" else "a ") + word


def _looks_measured(base: str, jnames: Sequence[str]) -> bool:
    if LOOKS_MEASURED.fullmatch(base):
        return True
    low = base.lower()
    if any(low == j.lower() for j in jnames):
        return True
    import difflib

    return bool(jnames) and bool(difflib.get_close_matches(base, jnames, n=1, cutoff=0.85))


def _unexpected(base: str, jnames: Sequence[str], lower_j: Mapping[str, str],
                fields: Sequence[Field]) -> str:
    if base.lower() in lower_j:
        return (f"differs from joint {lower_j[base.lower()]!r} only in case; rename it, or "
                "list it in --ignore")
    import difflib

    close = difflib.get_close_matches(base, jnames, n=1, cutoff=0.85)
    if close or re.fullmatch(r"(q|j|joint)\d+", base, re.IGNORECASE):
        near = f" (closest joint: {close[0]})" if close else ""
        return (f"looks like a joint column, but the robot has no joint {base!r}{near}; "
                f"its joints are {', '.join(jnames) or 'none'} (map it with --joint-names "
                "FILE_COLUMN=JOINT,..., or list it in --ignore)")
    if not fields:
        return ("looks like a measurement, but this file holds joint values only; list it "
                "in --ignore to drop it")
    expected = "; ".join(f.description or f.pattern for f in fields)
    return (f"looks like a measurement, but this instrument reads only: {expected}; list it "
            "in --ignore to drop it")


# --------------------------------------------------------------------------- writing
def joint_columns(robot: Any, n: int, angle_unit: str = "rad", length_unit: str = "m"
                  ) -> list[tuple[str, float]]:
    """Header names and SI->file factors of the joint columns.

    With a robot: ``{joint name}_{unit}``; without: ``q{i}_{unit}`` assuming revolute.
    """
    if robot is not None:
        out = []
        for j in robot.joints:
            u = angle_unit if j.kind == "revolute" else length_unit
            out.append((f"{j.name}_{u}", 1.0 / UNITS[u][1]))
        if len(out) != n:
            raise MeasurementFileError(f"robot {robot.name!r} has {len(out)} joints, the "
                                       f"measurements {n}")
        return out
    return [(f"q{i + 1}_{angle_unit}", 1.0 / UNITS[angle_unit][1]) for i in range(n)]


def format_table(columns: Sequence[tuple[str, Array]], tags: Mapping[str, str] | None = None,
                 comments: Sequence[str] = ()) -> str:
    """CSV text: optional tag line, ``#`` comments, header, rows (``%.15g``)."""
    lines: list[str] = []
    if tags:
        lines.append(TAG_PREFIX + " " + "; ".join(f"{k}={v}" for k, v in tags.items()))
    lines += [f"# {c}" for c in comments]
    lines.append(",".join(name for name, _ in columns))
    if columns:
        M = np.column_stack([np.asarray(v, dtype=float).reshape(-1) for _, v in columns])
        if not np.all(np.isfinite(M)):
            raise MeasurementFileError("refusing to write non-finite values")
        fmt = ",".join(["%.15g"] * M.shape[1])
        lines += [fmt % tuple(row) for row in M.tolist()]
    return "\n".join(lines) + "\n"


def write_table(path: str | os.PathLike[str], q: Array, observations: Sequence[tuple[str, Array,
                str]], robot: Any = None, tags: Mapping[str, str] | None = None,
                angle_unit: str = "rad", length_unit: str = "m",
                comments: Sequence[str] = ()) -> None:
    """Write a measurement CSV atomically.

    Args:
        path: output file (``-`` for stdout).
        q: (N, n) joint values [rad / m].
        observations: ``(base name, (N,) SI values, dimension)`` per column; the unit
            suffix is chosen from ``angle_unit`` / ``length_unit`` by dimension
            (``px`` for pixels, ``1`` for dimensionless).
        robot: gives the joint column names; without it ``q1 ... qn``.
        tags: first-line tags, e.g. ``{"instrument": "position", "name": "tracker"}``.
    """
    for u, dim in ((angle_unit, "angle"), (length_unit, "length")):
        if u not in UNITS or UNITS[u][0] != dim:
            raise MeasurementFileError(f"unknown {dim} unit {u!r}")
    q = np.asarray(q, dtype=float)
    cols: list[tuple[str, Array]] = []
    if q.ndim == 2 and q.shape[1] > 0:
        for k, (name, f) in enumerate(joint_columns(robot, q.shape[1], angle_unit,
                                                    length_unit)):
            cols.append((name, q[:, k] * f))
    for base, v, dim in observations:
        u = {"angle": angle_unit, "length": length_unit, "pixel": "px"}.get(dim, "1")
        cols.append((f"{base}_{u}", np.asarray(v, dtype=float) / UNITS[u][1]))
    atomic_write_text(path, format_table(cols, tags, comments))
