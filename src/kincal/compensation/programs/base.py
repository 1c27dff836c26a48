"""What every dialect reader produces: targets that know where their numbers are.

A program is read as bytes and decoded as Latin-1, a one-to-one map of bytes to
characters, so every byte the filter does not rewrite comes back unchanged (encoding,
CRLF line endings, comments, spacing).  A :class:`ProgramTarget` holds the text span
of each of its numbers (:class:`Slot`); :func:`render` replaces only the spans whose
value changed, each in the style of the number it replaces
(:mod:`~kincal.compensation.programs.numbers`).
"""

from __future__ import annotations

import bisect
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from kincal.compensation.configuration import Configuration
from kincal.compensation.programs.numbers import (
    NUMBER,
    NumberStyle,
    format_number,
    same_when_written,
    style_of,
)
from kincal.errors import KincalError
from kincal.spatial import rpy_near, xyzrpy_to_matrix

Array = NDArray[np.float64]


class ProgramError(KincalError):
    """Unreadable program content: one line naming file, line and column."""


@dataclass
class Slot:
    """One number of a program: where it is and what it says."""

    start: int
    end: int
    text: str
    value: float

    @property
    def style(self) -> NumberStyle:
        return style_of(self.text)


@dataclass(eq=False)
class ProgramTarget:
    """A target of a program (a point declaration or an inline target).

    Attributes:
        name: the point's name (``XP1``, ``p10``, ``P[3]``) or ``line N`` for inline ones.
        file: the file holding its numbers.
        line, column: 1-based position of its first number.
        kind: ``"pose"`` or ``"joints"``.
        slots: its numbers by component name (dialect-specific: ``x y z a b c``,
            ``q1 q2 q3 q4``, ``j1 ... j6``).
        config: the configuration it asks for (None: none).
        tool_key, base_key: the dialect's frame names (tool number, tooldata name, ...).
        note: why it cannot be filtered, when the reader already knows (else ``""``).
        used: referenced by a motion instruction (point declarations).
    """

    name: str
    file: str
    line: int
    column: int
    kind: str
    slots: dict[str, Slot]
    config: Configuration | None = None
    tool_key: Any = None
    base_key: Any = None
    note: str = ""
    used: bool = True
    extra: dict[str, Any] = field(default_factory=dict)

    def values(self, keys: Sequence[str]) -> Array:
        """The values of ``keys``: written ones, else those resolved from the program
        (``extra["resolved"]``: the components a partial target takes from the previous
        position)."""
        resolved = self.extra.get("resolved", {})
        return np.array([self.slots[k].value if k in self.slots else resolved[k]
                         for k in keys])


def read_program_text(path: str | os.PathLike[str]) -> str:
    """The file's bytes as Latin-1 text (one character per byte, nothing translated)."""
    try:
        data = Path(path).read_bytes()
    except IsADirectoryError:
        raise ProgramError("is a folder, not a program", source=str(path)) from None
    except OSError as exc:
        raise ProgramError(f"cannot read: {exc.strerror}", source=str(path)) from None
    if b"\x00" in data:
        line = data[:data.index(b"\x00")].count(b"\n") + 1
        raise ProgramError(f"line {line}: a NUL byte: not a text program", source=str(path))
    return data.decode("latin-1")


@lru_cache(maxsize=8)
def _line_starts(text: str) -> list[int]:
    return [0] + [m.end() for m in re.finditer("\n", text)]


def position(text: str, offset: int) -> tuple[int, int]:
    """1-based (line, column) of a character offset."""
    starts = _line_starts(text)
    line = bisect.bisect_right(starts, offset)
    return line, offset - starts[line - 1] + 1


def fail(path: str, text: str, offset: int, message: str) -> ProgramError:
    line, col = position(text, offset)
    return ProgramError(message, source=f"{path}:{line}:{col}")


def number_slot(path: str, text: str, start: int, end: int, what: str) -> Slot:
    """The :class:`Slot` of ``text[start:end]``, which must be one number."""
    raw = text[start:end]
    stripped = raw.strip()
    lead = len(raw) - len(raw.lstrip())
    m = NUMBER.fullmatch(stripped)
    if m is None:
        raise fail(path, text, start + lead, f"{what}: {stripped!r} is not a number")
    s = start + lead
    return Slot(s, s + len(stripped), stripped, float(stripped))


def render(text: str, edits: Mapping[int, tuple[Slot, float, int]], pad: bool = False) -> str:
    """``text`` with slots rewritten: ``{start: (slot, new value, min decimals)}``.

    A slot whose new value reads back the same in its style keeps its text.  With
    ``pad`` a shorter number is right-aligned in the old one's width (column-aligned
    formats such as FANUC's ``X =  1348.217  mm``); a longer one takes spaces before it.
    """
    out: list[str] = []
    pos = 0
    for start in sorted(edits):
        slot, value, digits = edits[start]
        if same_when_written(slot.value, value, slot.style, digits):
            continue
        new = format_number(value, slot.style, digits)
        begin = slot.start
        if pad:
            width = len(slot.text)
            if len(new) < width:
                new = " " * (width - len(new)) + new
            else:
                spaces = 0
                while spaces < len(new) - width and begin - spaces - 1 >= pos and \
                        text[begin - spaces - 1] == " " and text[begin - spaces - 2] == " ":
                    spaces += 1
                begin -= spaces
        out.append(text[pos:begin])
        out.append(new)
        pos = slot.end
    out.append(text[pos:])
    return "".join(out)


# --------------------------------------------------------------------------- frames file
@dataclass(frozen=True)
class Frames:
    """Tool and base (user) frames by number, as 4x4 [m]: ``T = Trans(x,y,z) Rz Ry Rx``."""

    tool: dict[str, Array]
    base: dict[str, Array]
    source: str = ""

    def get(self, which: str, key: Any, origin: str) -> Array:
        k = str(key)
        table = self.tool if which == "tool" else self.base
        if k in table:
            return table[k]
        if k in ("0", "None"):
            return np.eye(4)
        where = f" in {self.source}" if self.source else ""
        raise KincalError(f"{origin} uses {which} {k} but no {which} {k} is defined{where} "
                          f"(give it with --frames FILE)")


def pose_mm_deg(x: float, y: float, z: float, roll: float, pitch: float, yaw: float
                ) -> Array:
    """``Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)`` [m] from mm and deg: KUKA's
    ``X Y Z A B C`` (A = yaw, B = pitch, C = roll) and FANUC's ``X Y Z W P R`` (W = roll,
    P = pitch, R = yaw) alike."""
    d = np.pi / 180
    return xyzrpy_to_matrix([x * 1e-3, y * 1e-3, z * 1e-3, roll * d, pitch * d, yaw * d])


def xyz_rpy_mm_deg(T: Array, near: tuple[float, float, float], pole_deg: float = 5e-5
                   ) -> tuple[float, float, float, float, float, float]:
    """The inverse of :func:`pose_mm_deg`: ``x, y, z`` [mm] and ``roll, pitch, yaw``
    [deg] of ``T``, the representation of its rotation closest to ``near`` (the target's
    own roll, pitch, yaw): both Euler solutions and whole turns, and at pitch +-90 deg the
    split of roll and yaw that changes them least (:func:`kincal.spatial.rpy_near`;
    ``pole_deg``: half a unit of the written angles' last decimal)."""
    roll, pitch, yaw = (float(a) for a in np.degrees(
        rpy_near(T[:3, :3], np.radians(near), np.radians(pole_deg))))
    return (float(T[0, 3] * 1e3), float(T[1, 3] * 1e3), float(T[2, 3] * 1e3), roll, pitch,
            yaw)


def read_frames(path: str | None) -> Frames:
    """A frames file (YAML), or no frames.

    ::

        units: {length: mm, angle: deg}
        tool:                   # KUKA TOOL_DATA[n], FANUC UTOOL n
          1: {x: 0, y: 0, z: 200, rx: 0, ry: 0, rz: 0}
        base:                   # KUKA BASE_DATA[n], FANUC UFRAME n
          2: {x: 1000, y: -500, z: 0, rx: 0, ry: 0, rz: 90}

    Rotations as ``Rz(rz) Ry(ry) Rx(rx)``: KUKA's ``A, B, C`` are ``rz, ry, rx``,
    FANUC's ``W, P, R`` are ``rx, ry, rz``.
    """
    if path is None:
        return Frames({}, {})
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise KincalError(f"cannot read: {exc.strerror}", source=path) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise KincalError(f"{where}invalid YAML", source=path) from None
    if not isinstance(data, Mapping):
        raise KincalError("a frames file is a mapping with units, tool and base", source=path)
    units = data.get("units")
    if not isinstance(units, Mapping) or units.get("length") not in ("m", "mm") or \
            units.get("angle") not in ("rad", "deg"):
        raise KincalError("field 'units' must be {length: m|mm, angle: rad|deg}", source=path)
    ls = 1e-3 if units["length"] == "mm" else 1.0
    as_ = np.pi / 180 if units["angle"] == "deg" else 1.0
    out: dict[str, dict[str, Array]] = {"tool": {}, "base": {}}
    for which in ("tool", "base"):
        table = data.get(which) or {}
        if not isinstance(table, Mapping):
            raise KincalError(f"field '{which}' must map frame numbers to frames", source=path)
        for key, fr in table.items():
            f = f"{which}.{key}"
            if not isinstance(fr, Mapping) or set(fr) - {"x", "y", "z", "rx", "ry", "rz"}:
                raise KincalError(f"field '{f}' must be {{x, y, z, rx, ry, rz}}", source=path)
            try:
                v = [float(fr.get(k, 0.0)) for k in ("x", "y", "z", "rx", "ry", "rz")]
            except (TypeError, ValueError):
                raise KincalError(f"field '{f}': values must be numbers", source=path) from None
            out[which][str(key)] = xyzrpy_to_matrix([v[0] * ls, v[1] * ls, v[2] * ls,
                                                     v[3] * as_, v[4] * as_, v[5] * as_])
    return Frames(out["tool"], out["base"], path)
