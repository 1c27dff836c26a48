"""KUKA KRL: a ``.src`` and its ``.dat``.

What is read (KUKA System Software programming manual syntax, KSS 5.x to 8.x):

* ``.dat`` declarations ``DECL [GLOBAL] E6POS|POS|FRAME|E6AXIS|AXIS NAME={...}``: Cartesian
  aggregates ``{X 0.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0[,S 2,T 10][,E1 0.0 ...]}`` in mm and
  deg with ``R = Rz(A) Ry(B) Rx(C)`` (Z-Y'-X''), axis aggregates ``{A1 ...,A6 ...}`` in
  deg; ``DECL FDAT NAME={TOOL_NO n,BASE_NO m,IPO_FRAME #BASE,...}``.  Items the filter
  does not need (booleans, enums ``#BASE``, strings ``" "``, nested aggregates, other
  types such as ``LDAT`` / ``PDAT``) are skipped whatever they hold;
* ``.src`` motions ``PTP|LIN|CIRC|SPTP|SLIN|SCIRC|SPL`` with a point name or an inline
  aggregate (``CIRC`` / ``SCIRC`` have an auxiliary and an end point; ``_REL`` motions are
  relative and stay as they are), ``SPLINE ... ENDSPLINE`` and ``PTP_SPLINE ... ENDSPLINE``
  blocks, and the frames, followed in program order: ``$TOOL=TOOL_DATA[n]``,
  ``$BASE=BASE_DATA[n]``, ``$TOOL=$NULLFRAME``, ``BAS(#TOOL,n)``, ``BAS(#BASE,n)``,
  ``FDAT_ACT=name`` (the FDAT's TOOL_NO / BASE_NO), and the KSS 8 inline forms'
  ``WITH $TOOL=STOOL2(FP1), $BASE=SBASE(FP1.BASE_NO), $IPO_MODE=SIPO_MODE(FP1.IPO_FRAME)``
  (also ``$BASE=EK(K_ROOT(FP1.BASE_NO), ...)``), which hold for that motion (or, on a
  ``SPLINE ... WITH`` line, for the block's segments);
* an aggregate missing some of ``X Y Z A B C`` (``LIN {X 0, Y 0, Z 100}``) takes the
  missing ones from the previous position, as the controller does: the previous motion's
  target, expressed in this motion's frames
  (:mod:`~kincal.compensation.programs.sequence`).

A target whose value is computed at run time (``$POS_ACT``, a variable of the ``.src``,
an aggregate with expressions) is listed and left as it is; a point declared elsewhere is
listed as not filtered.  ``;`` starts a comment; keywords are case-insensitive.  A point's
frames are those active at the motions that use it; a point used under two different
frames is not filtered.  Files are Latin-1 with CRLF line endings; both are kept.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from kincal.compensation.configuration import kuka_configuration
from kincal.compensation.programs.base import (
    Array,
    ProgramTarget,
    Slot,
    fail,
    pose_mm_deg,
    position,
    read_program_text,
    xyz_rpy_mm_deg,
)
from kincal.compensation.programs.numbers import NUMBER
from kincal.errors import KincalError

POSE_KEYS = ("X", "Y", "Z", "A", "B", "C")
AXIS_KEYS = ("A1", "A2", "A3", "A4", "A5", "A6")
#: Items a target needs: a non-number there is bad content in a .dat.
_NEEDED = set(POSE_KEYS) | set(AXIS_KEYS) | {"S", "T"}
_DECL = re.compile(r"^[ \t]*(?:DECL[ \t]+)?(?:GLOBAL[ \t]+)?(E6POS|POS|FRAME|E6AXIS|AXIS|FDAT)"
                   r"[ \t]+([A-Za-z_$][\w$]*)[ \t]*=[ \t]*\{", re.IGNORECASE)
_SRC_DECL = re.compile(r"^[ \t]*(?:DECL[ \t]+)?(?:GLOBAL[ \t]+)?(?:E6POS|POS|FRAME|E6AXIS|AXIS)"
                       r"[ \t]+(.*)$", re.IGNORECASE)
_MOTION = re.compile(r"^[ \t]*(PTP|LIN|CIRC|SPTP|SLIN|SCIRC|SPL)(_REL)?\b[ \t]*",
                     re.IGNORECASE)
_BLOCK = re.compile(r"^[ \t]*(SPLINE|PTP_SPLINE)\b", re.IGNORECASE)
_ENDBLOCK = re.compile(r"^[ \t]*ENDSPLINE\b", re.IGNORECASE)
_DEF = re.compile(r"^[ \t]*(?:GLOBAL[ \t]+)?DEF(?:FCT[ \t]+\w+)?[ \t]+\w+[ \t]*\(([^)]*)\)",
                  re.IGNORECASE)
_CALL = re.compile(r"^[ \t]*([A-Za-z_][\w]*)[ \t]*\(", re.IGNORECASE)
#: Statement heads that look like calls but move nothing.
_NOT_CALLS = {"BAS", "IF", "WHILE", "UNTIL", "SWITCH", "WAIT", "RETURN", "EXIT", "INTERRUPT",
              "TRIGGER", "ANOUT", "PULSE", "HALT", "LOOP", "FOR", "REPEAT", "ELSE", "CASE",
              "DEFAULT", "GOTO", "CONTINUE", "BRAKE", "ON_ERROR_PROCEED"}
_TOOL = re.compile(r"\$TOOL[ \t]*=[ \t]*", re.IGNORECASE)
_BASE = re.compile(r"\$BASE[ \t]*=[ \t]*", re.IGNORECASE)
_IPO = re.compile(r"\$IPO_MODE[ \t]*=[ \t]*", re.IGNORECASE)
_BAS = re.compile(r"\bBAS[ \t]*\([ \t]*#(TOOL|BASE)[ \t]*,[ \t]*(\d+)[ \t]*\)", re.IGNORECASE)
_FDAT_ACT = re.compile(r"\bFDAT_ACT[ \t]*=[ \t]*([A-Za-z_$][\w$]*)", re.IGNORECASE)
_WITH = re.compile(r"\bWITH\b", re.IGNORECASE)
_NAME = re.compile(r"[A-Za-z_$][\w$]*")
_ITEM = re.compile(r"([A-Za-z_$][\w$]*(?:\[\])?)[ \t]*")
#: KUKA's standard $config.dat declares the home positions XHOME, XHOME1... as E6AXIS.
_HOME = re.compile(r"X?HOME\d*", re.IGNORECASE)


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


def _split(body: str) -> list[tuple[int, str]]:
    """(offset, text) of the top-level comma-separated parts of ``body`` (nested
    ``{}``, ``()``, ``[]`` and strings kept whole)."""
    if not any(ch in body for ch in '"{([})]'):
        parts, pos, flat = body.split(","), 0, []
        for part in parts:
            flat.append((pos, part))
            pos += len(part) + 1
        return flat
    out: list[tuple[int, str]] = []
    depth, begin, inside = 0, 0, False
    for i, ch in enumerate(body):
        if ch == '"':
            inside = not inside
        elif inside:
            continue
        elif ch in "{([":
            depth += 1
        elif ch in "})]":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append((begin, body[begin:i]))
            begin = i + 1
    out.append((begin, body[begin:]))
    return out


def _closing(text: str, start: int, end: int) -> int:
    """Index of the ``}`` closing the ``{`` at ``text[start]`` before ``end``, or -1."""
    first = text.find("}", start, end)
    if first >= 0 and text.find("{", start + 1, first) < 0 and \
            text.find('"', start, first) < 0:
        return first                         # the usual flat aggregate
    depth, inside = 0, False
    for i in range(start, end):
        ch = text[i]
        if ch == '"':
            inside = not inside
        elif inside:
            continue
        elif ch == "{":
            depth += 1
        elif ch == "}":
            depth -= 1
            if depth == 0:
                return i
    return -1


@dataclass
class Aggregate:
    """A ``{KEY value, ...}`` aggregate: numbers by key (upper case), other items raw
    (booleans, enums, strings, nested aggregates, expressions) with their offsets."""

    start: int
    end: int
    numbers: dict[str, Slot]
    other: dict[str, str]
    where: dict[str, int] = field(default_factory=dict)


def parse_aggregate(path: str, text: str, start: int) -> Aggregate:
    """The aggregate whose ``{`` is at ``text[start]`` (on one line)."""
    eol = text.find("\n", start)
    eol = len(text) if eol < 0 else eol
    close = _closing(text, start, eol)
    if close < 0:
        raise fail(path, text, start, "aggregate '{' is not closed on its line")
    numbers: dict[str, Slot] = {}
    other: dict[str, str] = {}
    where: dict[str, int] = {}
    body = text[start + 1:close]
    if not body.strip():
        return Aggregate(start, close + 1, numbers, other, where)
    for off, item in _split(body):
        at = start + 1 + off + len(item) - len(item.lstrip())
        b = item.strip()
        if not b:
            raise fail(path, text, at, "empty aggregate item")
        m = _ITEM.match(b)
        if m is None:
            raise fail(path, text, at, f"aggregate item {b!r} has no name")
        key = m.group(1).upper()
        value = b[m.end():]
        if not value:
            raise fail(path, text, at + m.end(), f"aggregate item {key} has no value")
        vstart = at + m.end()
        where[key] = vstart
        if NUMBER.fullmatch(value):
            numbers[key] = Slot(vstart, vstart + len(value), value, float(value))
        else:
            other[key] = value
    return Aggregate(start, close + 1, numbers, other, where)


def _target(path: str, text: str, name: str, agg: Aggregate, kind_hint: str,
            in_dat: bool = True) -> ProgramTarget:
    """The target of an aggregate.  In a ``.dat`` a needed item that is not a number is
    bad content; inline, it is an expression computed at run time."""
    line, col = position(text, agg.start)
    bad = sorted(set(agg.other) & _NEEDED)
    if bad and in_dat:
        k = bad[0]
        raise fail(path, text, agg.where[k], f"item {k}: {agg.other[k]!r} is not a number")
    axis = kind_hint in ("E6AXIS", "AXIS") or (
        kind_hint == "" and any(k in agg.numbers or k in agg.other for k in AXIS_KEYS))
    if bad:
        t = ProgramTarget(name, path, line, col, "joints" if axis else "pose", {})
        written = sorted((set(agg.numbers) & _NEEDED) - {"S", "T"})
        if written:          # absolute numbers that would need filtering, mixed with run time
            t.note = (f"partly computed at run time ({bad[0]} {agg.other[bad[0]]}), partly "
                      f"written ({', '.join(written)}): not filtered")
        else:
            t.note = f"computed at run time: {bad[0]} {agg.other[bad[0]]}"
            t.extra["kept"] = True
        return t
    if axis:
        slots = {k.lower(): agg.numbers[k] for k in AXIS_KEYS if k in agg.numbers}
        t = ProgramTarget(name, path, line, col, "joints", slots)
        if len(slots) < 6:
            t.extra["missing"] = [k.lower() for k in AXIS_KEYS if k not in agg.numbers]
        return t
    slots = {k.lower(): agg.numbers[k] for k in POSE_KEYS if k in agg.numbers}
    slots.update({k.lower(): agg.numbers[k] for k in ("S", "T") if k in agg.numbers})
    conf = None
    if "S" in agg.numbers or "T" in agg.numbers:
        s = int(agg.numbers["S"].value) if "S" in agg.numbers else None
        tt = int(agg.numbers["T"].value) if "T" in agg.numbers else None
        conf = kuka_configuration(s, tt)
    t = ProgramTarget(name, path, line, col, "pose", slots, conf)
    missing = [k.lower() for k in POSE_KEYS if k not in agg.numbers]
    if missing:
        t.extra["missing"] = missing
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


@dataclass
class _Fdat:
    tool: str | None
    base: str | None
    ipo: str | None


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
    fdat: dict[str, _Fdat] = {}
    no_value: set[str] = set()
    if dat_path is not None:
        dtext = read_program_text(dat_path)
        texts[str(dat_path)] = dtext
        for off, code in _lines(dtext):
            m = _DECL.match(code)
            if m is None:
                bare = _SRC_DECL.match(code)
                if bare and "=" not in code:
                    for part in bare.group(1).split(","):
                        nm = _NAME.match(part.strip())
                        if nm:
                            no_value.add(nm.group(0).upper())
                continue
            typ, name = m.group(1).upper(), m.group(2)
            agg = parse_aggregate(str(dat_path), dtext, off + m.end() - 1)
            if typ == "FDAT":
                tool, base = agg.numbers.get("TOOL_NO"), agg.numbers.get("BASE_NO")
                fdat[name.upper()] = _Fdat(None if tool is None else str(int(tool.value)),
                                           None if base is None else str(int(base.value)),
                                           agg.other.get("IPO_FRAME", "").upper() or None)
                continue
            t = _target(str(dat_path), dtext, name, agg, typ)
            t.used = False
            targets.append(t)
            by_name[name.upper()] = t
    if src_path is not None:
        stext = read_program_text(src_path)
        texts[str(src_path)] = stext
        reader = _SrcReader(str(src_path), stext, targets, by_name, fdat)
        reader.local |= no_value
        reader.read()
    return KrlProgram(texts, targets, str(src_path) if src_path else "",
                      str(dat_path) if dat_path else None)


@dataclass
class _Frames:
    """The frames a motion runs in: tool and base numbers (None: not known, ``why``
    says why) and the interpolation mode (``#BASE``: tool on the flange, ``#TCP``:
    external TCP)."""

    tool: str | None = "0"
    base: str | None = "0"
    ipo: str = "#BASE"
    why: str = ""

    def copy(self) -> _Frames:
        return _Frames(self.tool, self.base, self.ipo, self.why)


def _fdat_of(arg: str) -> str:
    """``FP1`` of ``FP1``, ``FP1.BASE_NO``, ``K_ROOT(FP1.BASE_NO)`` ..."""
    m = re.search(r"([A-Za-z_$][\w$]*)\s*\.\s*(?:BASE_NO|TOOL_NO|IPO_FRAME)", arg, re.I)
    if m:
        return m.group(1).upper()
    return arg.strip().strip("()").strip().upper()


class _SrcReader:
    """Follows a ``.src`` in program order: frames, spline blocks, motions."""

    def __init__(self, path: str, text: str, targets: list[ProgramTarget],
                 by_name: dict[str, ProgramTarget], fdat: dict[str, _Fdat]) -> None:
        self.path, self.text, self.targets = path, text, targets
        self.by_name, self.fdat = by_name, fdat
        self.frames = _Frames()
        self.block: _Frames | None = None
        self.previous: tuple[ProgramTarget, _Frames] | str = "the start of the program"
        self.local: set[str] = set()
        self.lines = _lines(text)
        for _, code in self.lines:
            d = _SRC_DECL.match(code)
            if d:
                for part in d.group(1).split(","):
                    nm = _NAME.match(part.strip())
                    if nm:
                        self.local.add(nm.group(0).upper())
            f = _DEF.match(code)
            if f:
                for part in f.group(1).split(","):
                    nm = _NAME.match(part.strip())
                    if nm:
                        self.local.add(nm.group(0).upper())

    # -- frames ------------------------------------------------------------------
    def _assign(self, fr: _Frames, var: str, value: str) -> None:
        """Apply ``$TOOL`` / ``$BASE`` / ``$IPO_MODE`` ``= value`` to ``fr``."""
        v = value.strip()
        vu = v.upper().replace(" ", "")
        ref = re.fullmatch(r"(TOOL|BASE)_DATA\[([A-Z_$][\w$]*)\.(?:TOOL|BASE)_NO\]", vu)
        if ref and var == ref.group(1):           # TOOL_DATA[FP1.TOOL_NO]
            f = self.fdat.get(ref.group(2))
            number = None if f is None else (f.tool if var == "TOOL" else f.base)
            if number is not None:
                v = vu = f"{var}_DATA[{number}]"
        if var == "TOOL":
            m = re.fullmatch(r"TOOL_DATA\[(\d+)\]", vu)
            if m or vu == "$NULLFRAME":
                fr.tool = m.group(1) if m else "0"
            elif vu.startswith(("STOOL2(", "STOOL(")):
                f = self.fdat.get(_fdat_of(v[v.index("(") + 1:]))
                fr.tool = None if f is None else f.tool
                if f is None:
                    fr.why = f"tool from {v}: that FDAT is not in this program's .dat"
            else:
                fr.tool, fr.why = None, f"$TOOL = {v}: computed at run time"
        elif var == "BASE":
            m = re.fullmatch(r"BASE_DATA\[(\d+)\]", vu)
            sb = re.fullmatch(r"SBASE\((\d+)\)", vu)
            if m or sb or vu == "$NULLFRAME":
                fr.base = m.group(1) if m else (sb.group(1) if sb else "0")
            elif vu.startswith(("SBASE(", "EK(")):
                f = self.fdat.get(_fdat_of(v[v.index("(") + 1:]))
                fr.base = None if f is None else f.base
                if f is None:
                    fr.why = f"base from {v}: that FDAT is not in this program's .dat"
            else:
                fr.base, fr.why = None, f"$BASE = {v}: computed at run time"
        elif var == "IPO_MODE":
            if vu.startswith("SIPO_MODE("):
                f = self.fdat.get(_fdat_of(v[v.index("(") + 1:]))
                fr.ipo = (f.ipo if f is not None and f.ipo else "#BASE")
            elif vu in ("#TCP", "#BASE"):
                fr.ipo = vu

    def _assignments(self, fr: _Frames, code: str) -> None:
        """Every ``$TOOL=``, ``$BASE=``, ``$IPO_MODE=`` in ``code`` (a WITH list or a
        statement), applied to ``fr``."""
        for _, part in _split(code):
            m = re.match(r"\s*\$(TOOL|BASE|IPO_MODE)\s*=\s*(.*)$", part, re.IGNORECASE | re.S)
            if m:
                self._assign(fr, m.group(1).upper(), m.group(2))

    def _statement(self, code: str) -> None:
        """Frames set by a statement outside a motion."""
        if _TOOL.search(code) or _BASE.search(code) or _IPO.search(code):
            self._assignments(self.frames, code)
        for m in _BAS.finditer(code):
            if m.group(1).upper() == "TOOL":
                self.frames.tool = m.group(2)
            else:
                self.frames.base = m.group(2)
        for m in _FDAT_ACT.finditer(code):
            f = self.fdat.get(m.group(1).upper())
            if f is not None:
                self.frames.tool = f.tool if f.tool is not None else self.frames.tool
                self.frames.base = f.base if f.base is not None else self.frames.base
                self.frames.ipo = f.ipo or "#BASE"
            else:
                self.frames.tool = self.frames.base = None
                self.frames.why = (f"FDAT_ACT = {m.group(1)}: that FDAT is not in this "
                                   "program's .dat")

    # -- program -----------------------------------------------------------------
    def read(self) -> None:
        for off, code in self.lines:
            if _ENDBLOCK.match(code):
                self.block = None
                continue
            b = _BLOCK.match(code)
            if b:
                self.block = self.frames.copy()
                w = _WITH.search(code, b.end())
                if w:
                    self._assignments(self.block, code[w.end():])
                continue
            mm = _MOTION.match(code)
            if mm is None:
                self._statement(code)
                c = _CALL.match(code)
                if c and c.group(1).upper() not in _NOT_CALLS and "=" not in code[:c.end()]:
                    self.previous = f"a call of {c.group(1)}"
                continue
            self._motion(off, code, mm)

    def _motion(self, off: int, code: str, mm: re.Match[str]) -> None:
        path, text = self.path, self.text
        instr = mm.group(1).upper()
        relative = mm.group(2) is not None
        fr = (self.block or self.frames).copy()
        w = _WITH.search(code, mm.end())
        if w:
            self._assignments(fr, code[w.end():])
        line_end = off + (w.start() if w else len(code))
        pos = off + mm.end()
        args = 2 if instr in ("CIRC", "SCIRC") else 1
        for k in range(args):
            while pos < line_end and text[pos] in " \t,":
                pos += 1
            if pos >= line_end:
                raise fail(path, text, pos, f"{instr} needs a target")
            end_point = k == args - 1
            if text[pos] == "{":
                agg = parse_aggregate(path, text, pos)
                t = _target(path, text, f"line {position(text, pos)[0]}", agg, "", False)
                t.used = False
                self.targets.append(t)
                pos = agg.end
                self._use(t, fr, relative, end_point)
                continue
            nm = _NAME.match(text, pos)
            if nm is None:
                raise fail(path, text, pos, "expected a point name or an aggregate '{'")
            pos = nm.end()
            self._named(nm.group(0), pos - len(nm.group(0)), fr, relative, end_point)

    def _named(self, name: str, at: int, fr: _Frames, relative: bool, end_point: bool
               ) -> None:
        """A motion to a point by name."""
        point = self.by_name.get(name.upper())
        if point is not None:
            self._use(point, fr, relative, end_point)
            return
        line, col = position(self.text, at)
        t = ProgramTarget(name, self.path, line, col, "computed", {})
        if name.startswith("$"):
            t.note = f"the robot's own position at run time ({name}): needs no filtering"
            t.extra["kept"] = True
        elif _HOME.fullmatch(name):
            t.kind = "joints"
            t.note = f"{name}: an axis position (E6AXIS) of $config.dat: kept"
            t.extra["kept"] = True
        elif name.upper() in self.local:
            t.note = f"computed at run time: {name} is a variable without a written value"
            t.extra["kept"] = True
        else:
            t.note = (f"{name} is declared outside this program's .dat ($config.dat or "
                      "another module): not read")
        self.targets.append(t)
        if end_point:
            self.previous = f"{name}, whose value is not in this program"

    def _use(self, t: ProgramTarget, fr: _Frames, relative: bool, end_point: bool) -> None:
        """Record a motion to target ``t`` in frames ``fr``."""
        if relative:
            t.note = t.note or ("relative motion (_REL): left as it is" if t.name.startswith(
                "line ") else "used by a relative motion (_REL): left as it is")
            t.extra["kept"] = True
        elif t.kind == "pose" and fr.ipo == "#TCP":
            t.note = t.note or ("external TCP ($IPO_MODE #TCP: the tool stands in the cell, "
                                "the workpiece moves with the flange): not supported")
        elif t.kind == "pose" and (fr.tool is None or fr.base is None):
            t.note = t.note or f"frames not known: {fr.why}"
        if t.used and t.kind == "pose" and (t.tool_key, t.base_key) != (fr.tool, fr.base):
            t.note = t.note or (f"used with tool {t.tool_key}/base {t.base_key} and with "
                                f"tool {fr.tool}/base {fr.base}")
        if "missing" in t.extra:
            prev = self.previous
            if t.used and t.extra.get("previous") is not None and \
                    t.extra["previous"] != prev:
                t.note = t.note or "a partial point used after two different positions"
            t.extra["previous"] = prev
        t.used = True
        t.tool_key, t.base_key = fr.tool, fr.base
        if end_point:
            if relative:
                self.previous = "a relative motion"
            elif not t.slots:
                self.previous = f"{t.name}, computed at run time"
            elif t.note:
                self.previous = f"{t.name}, which is not filtered"
            else:
                self.previous = (t, fr)


# --------------------------------------------------------------------------- values
def pose_of(t: ProgramTarget) -> Array:
    """The target's pose in its base frame [m, rad] from X, Y, Z [mm], A, B, C [deg]."""
    x, y, z, a, b, c = t.values(("x", "y", "z", "a", "b", "c"))
    return pose_mm_deg(x, y, z, c, b, a)


def pose_values(t: ProgramTarget, T: Array) -> dict[str, float]:
    """X, Y, Z [mm], A, B, C [deg] of pose T, angles near the target's own (its written
    or, for a partial aggregate, its resolved ones)."""
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
_MODULE_NAME = re.compile(r"[A-Za-z_$][\w$]{0,23}", re.ASCII)


def rename_module(text: str, old: str, new: str, source: str = "") -> str:
    """``text`` of a ``.src`` / ``.dat`` with its module's ``DEF old(`` / ``DEFDAT old``
    renamed to ``new`` (the controller requires them to match the file name; names
    compare case-insensitively).  Other routines of the file keep their names; nothing
    else changes.  A ``new`` that is no KRL name is a one-line error."""
    if old.lower() == new.lower():
        return text
    if not _MODULE_NAME.fullmatch(new):
        raise KincalError(f"{new!r} is not a KRL module name (a letter, _ or $ first, then "
                          "letters, digits, _ or $; at most 24 characters): the file name "
                          "must be one, since DEF / DEFDAT follow it", source=source or None)
    return _MODULE.sub(lambda m: m.group(1) + new if m.group(2).lower() == old.lower()
                       else m.group(0), text)
