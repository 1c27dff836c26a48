"""KUKA KRL: a ``.src`` and its ``.dat``.

What is read (KUKA System Software programming manual syntax):

* ``.dat`` declarations ``DECL [GLOBAL] E6POS|POS|FRAME|E6AXIS|AXIS NAME={...}``: Cartesian
  aggregates ``{X 0.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0[,S 2,T 10][,E1 0.0 ...]}`` in mm and
  deg with ``R = Rz(A) Ry(B) Rx(C)`` (Z-Y'-X''), axis aggregates ``{A1 ...,A6 ...}`` in
  deg; ``DECL FDAT NAME={TOOL_NO n,BASE_NO m,...}``;
* ``.src`` motions ``PTP|LIN|CIRC|SPTP|SLIN|SCIRC`` with a point name or an inline
  aggregate (``CIRC`` has an auxiliary and an end point; ``_REL`` motions are relative
  and stay as they are), and the active frames: ``$TOOL=TOOL_DATA[n]``,
  ``$BASE=BASE_DATA[n]``, ``$TOOL=$NULLFRAME``, ``BAS(#TOOL,n)``, ``BAS(#BASE,n)`` and
  ``FDAT_ACT=name`` (the FDAT's TOOL_NO / BASE_NO), followed in program order.

``;`` starts a comment; keywords are case-insensitive.  A point's frames are those
active at the motions that use it; a point used under two different frames is not
filtered.  Files are Latin-1 with CRLF line endings; both are kept.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kincal.compensation.configuration import kuka_configuration
from kincal.compensation.programs.base import (
    Array,
    ProgramTarget,
    Slot,
    fail,
    number_slot,
    pose_mm_deg,
    position,
    read_program_text,
    xyz_rpy_mm_deg,
)
from kincal.errors import KincalError

POSE_KEYS = ("X", "Y", "Z", "A", "B", "C")
AXIS_KEYS = ("A1", "A2", "A3", "A4", "A5", "A6")
_TYPES = ("E6POS", "POS", "FRAME", "E6AXIS", "AXIS", "FDAT")
_DECL = re.compile(r"^[ \t]*(?:DECL[ \t]+)?(?:GLOBAL[ \t]+)?(E6POS|POS|FRAME|E6AXIS|AXIS|FDAT)"
                   r"[ \t]+([A-Za-z_$][\w$]*)[ \t]*=[ \t]*\{", re.IGNORECASE)
_MOTION = re.compile(r"^[ \t]*(PTP|LIN|CIRC|SPTP|SLIN|SCIRC)(_REL)?\b[ \t]*", re.IGNORECASE)
_TOOL = re.compile(r"\$TOOL[ \t]*=[ \t]*(?:TOOL_DATA[ \t]*\[[ \t]*(\d+)[ \t]*\]|(\$NULLFRAME))",
                   re.IGNORECASE)
_BASE = re.compile(r"\$BASE[ \t]*=[ \t]*(?:BASE_DATA[ \t]*\[[ \t]*(\d+)[ \t]*\]|(\$NULLFRAME))",
                   re.IGNORECASE)
_BAS = re.compile(r"\bBAS[ \t]*\([ \t]*#(TOOL|BASE)[ \t]*,[ \t]*(\d+)[ \t]*\)", re.IGNORECASE)
_FDAT_ACT = re.compile(r"\bFDAT_ACT[ \t]*=[ \t]*([A-Za-z_$][\w$]*)", re.IGNORECASE)
_NAME = re.compile(r"[A-Za-z_$][\w$]*")


def _code_end(line: str) -> int:
    """Index where a line's comment starts (``;`` outside a string), or its length."""
    inside = False
    for i, ch in enumerate(line):
        if ch == '"':
            inside = not inside
        elif ch == ";" and not inside:
            return i
    return len(line)


def _lines(text: str) -> list[tuple[int, str]]:
    """(offset, code part) of every line (the line ending and comment removed)."""
    out = []
    pos = 0
    for raw in text.splitlines(keepends=True):
        body = raw.rstrip("\r\n")
        out.append((pos, body[:_code_end(body)]))
        pos += len(raw)
    return out


@dataclass
class Aggregate:
    """A ``{KEY value, ...}`` aggregate: numbers by key (upper case), other items raw."""

    start: int
    end: int
    numbers: dict[str, Slot]
    other: dict[str, str]


def parse_aggregate(path: str, text: str, start: int) -> Aggregate:
    """The aggregate whose ``{`` is at ``text[start]`` (on one line)."""
    eol = text.find("\n", start)
    eol = len(text) if eol < 0 else eol
    close = text.find("}", start, eol)
    if close < 0:
        raise fail(path, text, start, "aggregate '{' is not closed on its line")
    numbers: dict[str, Slot] = {}
    other: dict[str, str] = {}
    pos = start + 1
    for item in text[start + 1:close].split(","):
        lead = len(item) - len(item.lstrip())
        body = item.strip()
        at = pos + lead
        pos += len(item) + 1
        if not body:
            raise fail(path, text, at, "empty aggregate item")
        m = re.match(r"([A-Za-z_$][\w$]*(?:\[\])?)[ \t]*", body)
        if m is None:
            raise fail(path, text, at, f"aggregate item {body!r} has no name")
        key = m.group(1).upper()
        value = body[m.end():]
        if not value:
            raise fail(path, text, at + m.end(), f"aggregate item {key} has no value")
        vstart = at + m.end()
        if value[0] in "#\"":
            other[key] = value
            continue
        numbers[key] = number_slot(path, text, vstart, vstart + len(value), f"item {key}")
    return Aggregate(start, close + 1, numbers, other)


def _target(path: str, text: str, name: str, agg: Aggregate, kind_hint: str) -> ProgramTarget:
    keys = set(agg.numbers)
    line, col = position(text, agg.start)
    if kind_hint in ("E6AXIS", "AXIS") or (kind_hint == "" and "A1" in keys):
        slots = {k.lower(): agg.numbers[k] for k in AXIS_KEYS if k in agg.numbers}
        t = ProgramTarget(name, path, line, col, "joints", slots)
        if len(slots) < 6:
            t.note = "partial axis aggregate (missing axes keep the current value)"
        return t
    slots = {k.lower(): agg.numbers[k] for k in POSE_KEYS if k in agg.numbers}
    slots.update({k.lower(): agg.numbers[k] for k in ("S", "T") if k in agg.numbers})
    conf = None
    if "S" in agg.numbers or "T" in agg.numbers:
        s = int(agg.numbers["S"].value) if "S" in agg.numbers else None
        tt = int(agg.numbers["T"].value) if "T" in agg.numbers else None
        conf = kuka_configuration(s, tt)
    t = ProgramTarget(name, path, line, col, "pose", slots, conf)
    if len(set(slots) & set("xyzabc")) < 6:
        t.note = "partial aggregate (missing components keep the current value)"
    return t


@dataclass
class KrlProgram:
    """A read KRL program: its files' text and its targets."""

    texts: dict[str, str]
    targets: list[ProgramTarget]
    src: str
    dat: str | None


def companion_dat(src: Path) -> Path | None:
    """The ``.dat`` beside a ``.src`` (same stem, any case)."""
    for p in src.parent.iterdir() if src.parent.is_dir() else []:
        if p.stem.lower() == src.stem.lower() and p.suffix.lower() == ".dat":
            return p
    return None


def read_krl(path: str) -> KrlProgram:
    """Read a ``.src`` (and its ``.dat``) or a lone ``.dat``."""
    p = Path(path)
    if p.suffix.lower() == ".dat":
        src_path = next((q for q in p.parent.iterdir() if q.stem.lower() == p.stem.lower()
                         and q.suffix.lower() == ".src"), None)
        dat_path: Path | None = p
    else:
        src_path, dat_path = p, companion_dat(p)
    texts: dict[str, str] = {}
    targets: list[ProgramTarget] = []
    by_name: dict[str, ProgramTarget] = {}
    fdat: dict[str, tuple[str | None, str | None]] = {}
    if dat_path is not None:
        dtext = read_program_text(dat_path)
        texts[str(dat_path)] = dtext
        for off, code in _lines(dtext):
            m = _DECL.match(code)
            if m is None:
                continue
            typ, name = m.group(1).upper(), m.group(2)
            agg = parse_aggregate(str(dat_path), dtext, off + m.end() - 1)
            if typ == "FDAT":
                tool = agg.numbers.get("TOOL_NO")
                base = agg.numbers.get("BASE_NO")
                fdat[name.upper()] = (None if tool is None else str(int(tool.value)),
                                      None if base is None else str(int(base.value)))
                continue
            t = _target(str(dat_path), dtext, name, agg, typ)
            t.used = False
            targets.append(t)
            by_name[name.upper()] = t
    if src_path is not None:
        stext = read_program_text(src_path)
        texts[str(src_path)] = stext
        _read_src(str(src_path), stext, targets, by_name, fdat)
    return KrlProgram(texts, targets, str(src_path) if src_path else "",
                      str(dat_path) if dat_path else None)


def _read_src(path: str, text: str, targets: list[ProgramTarget],
              by_name: dict[str, ProgramTarget], fdat: dict[str, tuple[str | None, str | None]]
              ) -> None:
    tool: str = "0"
    base: str = "0"
    for off, code in _lines(text):
        for m in _TOOL.finditer(code):
            tool = m.group(1) or "0"
        for m in _BASE.finditer(code):
            base = m.group(1) or "0"
        for m in _BAS.finditer(code):
            if m.group(1).upper() == "TOOL":
                tool = m.group(2)
            else:
                base = m.group(2)
        for m in _FDAT_ACT.finditer(code):
            t_no, b_no = fdat.get(m.group(1).upper(), (None, None))
            tool = t_no if t_no is not None else tool
            base = b_no if b_no is not None else base
        mm = _MOTION.match(code)
        if mm is None:
            continue
        relative = mm.group(2) is not None
        rest_at = off + mm.end()
        args = 2 if mm.group(1).upper() in ("CIRC", "SCIRC") else 1
        pos = rest_at
        for _ in range(args):
            while pos < off + len(code) and text[pos] in " \t,":
                pos += 1
            if pos >= off + len(code):
                raise fail(path, text, pos, f"{mm.group(1).upper()} needs a target")
            if text[pos] == "{":
                agg = parse_aggregate(path, text, pos)
                t = _target(path, text, f"line {position(text, pos)[0]}", agg, "")
                t.tool_key, t.base_key = tool, base
                if relative:
                    t.note = "relative motion (_REL): left as it is"
                targets.append(t)
                pos = agg.end
                continue
            nm = _NAME.match(text, pos)
            if nm is None:
                raise fail(path, text, pos, "expected a point name or an aggregate '{'")
            pos = nm.end()
            point = by_name.get(nm.group(0).upper())
            if point is None:
                continue                     # a variable declared elsewhere ($config.dat)
            if relative:
                point.note = "used by a relative motion (_REL): left as it is"
            if point.used and (point.tool_key, point.base_key) != (tool, base):
                point.note = (f"used with tool {point.tool_key}/base {point.base_key} and with "
                              f"tool {tool}/base {base}")
            point.used = True
            point.tool_key, point.base_key = tool, base


# --------------------------------------------------------------------------- values
def pose_of(t: ProgramTarget) -> Array:
    """The target's pose in its base frame [m, rad] from X, Y, Z [mm], A, B, C [deg]."""
    x, y, z, a, b, c = t.values(("x", "y", "z", "a", "b", "c"))
    return pose_mm_deg(x, y, z, c, b, a)


def pose_values(t: ProgramTarget, T: Array) -> dict[str, float]:
    """X, Y, Z [mm], A, B, C [deg] of pose T, angles near the target's own."""
    a, b, c = t.values(("a", "b", "c"))
    x, y, z, roll, pitch, yaw = xyz_rpy_mm_deg(T, (c, b, a))
    return {"x": x, "y": y, "z": z, "a": yaw, "b": pitch, "c": roll}


def config_values(t: ProgramTarget, axes: Array, signs: Array) -> dict[str, float]:
    """S and T of the filtered joints (axes in deg; signs shoulder, elbow, wrist), for the
    ones the target writes.  S keeps its bits above 2."""
    out: dict[str, float] = {}
    if "t" in t.slots:
        out["t"] = float(sum(int(axes[k] < 0) << k for k in range(6)))
    if "s" in t.slots and np.all(signs != 0):
        low = int(signs[0] < 0) + 2 * int(signs[1] > 0) + 4 * int(signs[2] < 0)
        out["s"] = float((int(t.slots["s"].value) & ~7) | low)
    return out


def digits(key: str) -> int:
    """Minimum decimals: 4 for mm and deg, none for S and T."""
    return 0 if key in ("s", "t") else 4


# --------------------------------------------------------------------------- file names
_MODULE = re.compile(r"^([ \t]*(?:GLOBAL[ \t]+)?DEF(?:DAT)?[ \t]+)([A-Za-z_$][\w$]*)",
                     re.IGNORECASE | re.MULTILINE)
#: A KRL name: a letter, _ or $ first, then letters, digits, _ or $; at most 24 characters.
_NAME = re.compile(r"[A-Za-z_$][\w$]{0,23}", re.ASCII)


def rename_module(text: str, old: str, new: str, source: str = "") -> str:
    """``text`` of a ``.src`` / ``.dat`` with its module's ``DEF old(`` / ``DEFDAT old``
    renamed to ``new`` (the controller requires them to match the file name; names
    compare case-insensitively).  Other routines of the file keep their names; nothing
    else changes.  A ``new`` that is no KRL name is a one-line error."""
    if old.lower() == new.lower():
        return text
    if not _NAME.fullmatch(new):
        raise KincalError(f"{new!r} is not a KRL module name (a letter, _ or $ first, then "
                          "letters, digits, _ or $; at most 24 characters): the file name "
                          "must be one, since DEF / DEFDAT follow it", source=source or None)
    return _MODULE.sub(lambda m: m.group(1) + new if m.group(2).lower() == old.lower()
                       else m.group(0), text)
