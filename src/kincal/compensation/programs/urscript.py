"""Universal Robots URScript (``.script``), as written by hand or exported by PolyScope.

What is read (URScript manual syntax), in program (text) order:

* motion calls ``movej``, ``movel``, ``movep``, ``movec`` (a via pose and an end pose),
  ``optimovej``, ``optimovel`` (UR 5.21 / 10.8), ``servoj``, ``servoc``: their target is a
  pose literal ``p[x, y, z, rx, ry, rz]`` (m; rotation vector, rad), a joint list
  ``[q1, ..., q6]`` (rad), ``get_inverse_kin(pose, qnear=q)`` (PolyScope's MoveJ: the pose
  is the target, the controller's solution is the one nearest ``qnear``), or a variable;
* assignments ``[global|local] name = value``: a use of ``name`` takes the value assigned
  last before it in the text (a variable assigned twice gives two targets).  A value that
  is not a literal of numbers (``pose_trans(...)``, ``[params[2] / 1000, ...]``,
  ``get_actual_tcp_pose()``) is computed at run time: listed, not filtered;
* ``pose_trans(feature, pose)`` of two written poses (PolyScope's waypoints relative to a
  feature): ``pose`` is the target, written in the frame ``feature``, which stays (when
  the feature is itself a motion target, the pose is relative to it, as ``_REL`` in KRL:
  left as it is);
* ``set_tcp(p[...])`` sets the tool for the motions after it.

``#`` starts a comment.  Poses are in the robot's base frame.  URScript states no
configuration: the controller takes the solution nearest the current joints, so each
Cartesian target is solved from the joint target before it (or its ``qnear``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from kincal.compensation.programs.base import (
    Array,
    Frames,
    ProgramTarget,
    Slot,
    fail,
    position,
    read_program_text,
)
from kincal.compensation.programs.numbers import NUMBER
from kincal.spatial import exp_so3, homogeneous, log_so3

JOINT_KEYS = ("j1", "j2", "j3", "j4", "j5", "j6")
POSE_KEYS = ("x", "y", "z", "rx", "ry", "rz")
#: Motion calls and how many targets each takes first.
MOVES = {"movej": 1, "movel": 1, "movep": 1, "movec": 2, "optimovej": 1, "optimovel": 1,
         "servoj": 1, "servoc": 1}
_MOVE = re.compile(r"\b(" + "|".join(MOVES) + r")\s*\(")
_ASSIGN = re.compile(r"^[ \t]*(?:(?:global|local)[ \t]+)?([A-Za-z_]\w*)[ \t]*=(?!=)[ \t]*",
                     re.MULTILINE)
_TCP = re.compile(r"\bset_tcp\s*\(")
_IDENT = re.compile(r"[A-Za-z_]\w*")
_IK = re.compile(r"get_inverse_kin\s*\(")
#: A token that starts like a number and has no operator: a number or a misspelt one.
_NUMBERLIKE = re.compile(r"[-+]?\.?\d[\w.]*")


def code_of(text: str) -> str:
    """``text`` with ``#`` comments blanked (outside strings)."""
    out = list(text)
    inside: str | None = None
    comment = False
    for i, ch in enumerate(text):
        if ch == "\n":
            comment = False
            inside = None
            continue
        if comment:
            if ch != "\r":
                out[i] = " "
        elif inside:
            if ch == inside:
                inside = None
        elif ch in "\"'":
            inside = ch
        elif ch == "#":
            comment = True
            out[i] = " "
    return "".join(out)


def _close(code: str, start: int) -> int:
    """Index of the bracket closing the one at ``code[start]`` (``(`` or ``[``), or -1."""
    if code[start] == "[":                   # the usual flat list
        first = code.find("]", start)
        if first >= 0 and not any(ch in code[start + 1:first] for ch in "[(\n"):
            return first
    depth = 0
    for i in range(start, len(code)):
        if code[i] in "([":
            depth += 1
        elif code[i] in ")]":
            depth -= 1
            if depth == 0:
                return i
        elif code[i] == "\n" and depth == 0:
            return -1
    return -1


def _numbers(text: str, code: str, start: int) -> tuple[list[Slot] | None, int]:
    """The numbers of the list ``[a, b, ...]`` at ``code[start] == "["`` and the index
    after it; None for a list that is not all plain numbers (computed at run time)."""
    end = _close(code, start)
    if end < 0:
        return None, -1
    slots: list[Slot] = []
    pos = start + 1
    for part in code[start + 1:end].split(","):
        s = part.strip()
        lead = len(part) - len(part.lstrip())
        if NUMBER.fullmatch(s) is None:
            return None, end + 1
        slots.append(Slot(pos + lead, pos + lead + len(s), s, float(s)))
        pos += len(part) + 1
    return slots, end + 1


@dataclass
class _Value:
    """What an expression is: a pose or joint literal (its slots), or computed."""

    kind: str                      # pose | joints | computed | unknown
    at: int                        # offset of the literal's '[' (or the expression)
    slots: list[Slot] | None = None
    text: str = ""


def _args(code: str, start: int) -> list[tuple[int, str]]:
    """The top-level arguments of a call whose ``(`` is at ``start - 1``."""
    depth, begin, out = 0, start, []
    for i in range(start, len(code)):
        ch = code[i]
        if ch in "[(":
            depth += 1
        elif ch in "])":
            if depth == 0:
                out.append((begin, code[begin:i]))
                return out
            depth -= 1
        elif ch == "," and depth == 0:
            out.append((begin, code[begin:i]))
            begin = i + 1
    out.append((begin, code[begin:]))
    return out


class _Reader:
    """Reads one file: assignments by name in text order, then the motions."""

    def __init__(self, path: str, text: str) -> None:
        self.path, self.text, self.code = path, text, code_of(text)
        self.assigned: dict[str, list[tuple[int, _Value]]] = {}
        for m in _ASSIGN.finditer(self.code):
            eol = self.code.find("\n", m.end())
            expr_end = len(self.code) if eol < 0 else eol
            self.assigned.setdefault(m.group(1), []).append(
                (m.start(1), self.literal(m.end(), expr_end)))

    def literal(self, start: int, end: int) -> _Value:
        """The value of the expression ``code[start:end]`` (a literal or computed)."""
        raw = self.code[start:end]
        lead = len(raw) - len(raw.lstrip())
        s = raw.strip()
        at = start + lead
        if s.startswith(("p[", "[")):
            bracket = at + (1 if s.startswith("p") else 0)
            slots, after = _numbers(self.text, self.code, bracket)
            if slots is not None and not self.code[after:end].strip():
                return _Value("pose" if s.startswith("p") else "joints", bracket, slots, s)
            close = _close(self.code, bracket)
            parts = [x.strip() for x in self.code[bracket + 1:close].split(",")] \
                if close > 0 else []
            _check_literal(self, _Value("computed", at, None, s))     # misspelt numbers
            numeric = sum(NUMBER.fullmatch(x) is not None for x in parts)
            if 0 < numeric < len(parts) and not self.code[close + 1:end].strip():
                return _Value("unknown", at, None,
                              f"{_short(s)}: partly computed at run time, partly written")
        if s.startswith("p[") and _close(self.code, at + 1) < 0:
            raise fail(self.path, self.text, at + 1, "pose: '[' is not closed")
        return _Value("computed", at, None, s)

    def value(self, start: int, end: int, use: int) -> _Value:
        """An argument: a literal, a variable (its value before ``use``), or computed."""
        raw = self.code[start:end]
        s = raw.strip()
        at = start + len(raw) - len(raw.lstrip())
        if _IDENT.fullmatch(s):
            before = [v for pos, v in self.assigned.get(s, []) if pos < use]
            if before:
                return before[-1]
            later = self.assigned.get(s, [])
            if len(later) == 1:        # assigned once, further down (a global of a def)
                return later[0][1]
            reason = ("assigned only after its use" if later else
                      "not assigned in this file (a function argument or an "
                      "installation variable)")
            return _Value("unknown", at, None, f"{s}: {reason}")
        return self.literal(start, end)


def _check_literal(reader: _Reader, v: _Value) -> None:
    """A list with a misspelt number (``-0.17q17``: no expression starts with a digit) is
    bad content: one line with its column."""
    s = v.text
    if v.kind != "computed" or not s.startswith(("p[", "[")):
        return
    bracket = v.at + (1 if s.startswith("p") else 0)
    end = _close(reader.code, bracket)
    if end < 0:
        raise fail(reader.path, reader.text, bracket, "list: '[' is not closed")
    pos = bracket + 1
    for raw in reader.code[bracket + 1:end].split(","):
        p = raw.strip()
        if _NUMBERLIKE.fullmatch(p) and NUMBER.fullmatch(p) is None:
            what = "pose" if s.startswith("p") else "joint list"
            raise fail(reader.path, reader.text, pos + len(raw) - len(raw.lstrip()),
                       f"{what}: {p!r} is not a number")
        pos += len(raw) + 1


@dataclass
class UrProgram:
    texts: dict[str, str]
    targets: list[ProgramTarget]


_POSE_TRANS = re.compile(r"pose_trans\s*\(")


def _target_of(reader: _Reader, off: int, a: str, use: int) -> tuple[_Value, _Value | None]:
    """A motion's target argument ``a`` at ``off``: its value and, for
    ``pose_trans(F, P)`` of two written poses (a PolyScope waypoint relative to a feature),
    ``F`` as the frame the pose ``P`` is written in."""
    s = a.strip()
    pt = _POSE_TRANS.match(s)
    if pt is not None:
        at = off + len(a) - len(a.lstrip())
        inner = _args(reader.code, at + pt.end())
        if len(inner) == 2:
            frame = reader.value(inner[0][0], inner[0][0] + len(inner[0][1]), use)
            pose = reader.value(inner[1][0], inner[1][0] + len(inner[1][1]), use)
            if frame.kind == pose.kind == "pose" and frame.slots and len(frame.slots) == 6:
                return pose, frame
    return reader.value(off, off + len(a), use), None


def _events(reader: _Reader) -> list[tuple[int, str, object]]:
    """(offset, what, data) of every set_tcp and motion target, in text order."""
    code = reader.code
    events: list[tuple[int, str, object]] = []
    for m in _TCP.finditer(code):
        args = _args(code, m.end())
        v = reader.value(args[0][0], args[0][0] + len(args[0][1]), m.start())
        events.append((m.start(), "tcp", v))
    for m in _MOVE.finditer(code):
        args = _args(code, m.end())
        for off, a in args[:MOVES[m.group(1)]]:
            s = a.strip()
            ik = _IK.match(s)
            if ik is not None:
                at = off + len(a) - len(a.lstrip())
                inner = _args(code, at + ik.end())
                v, user = _target_of(reader, inner[0][0], inner[0][1], m.start())
                seed: _Value | None = None
                for ioff, ia in inner[1:]:
                    kw = re.match(r"\s*(\w+)\s*=", ia)
                    if kw and kw.group(1) == "qnear":
                        seed = reader.value(ioff + kw.end(), ioff + len(ia), m.start())
                    elif kw and kw.group(1) == "tcp":
                        v = _Value("computed", v.at, None,
                                   "get_inverse_kin with a tcp of its own")
                events.append((m.start(), m.group(1), (v, seed, user)))
                continue
            v, user = _target_of(reader, off, a, m.start())
            _check_literal(reader, v)
            events.append((m.start(), m.group(1), (v, None, user)))
    events.sort(key=lambda e: e[0])
    return events


def read_urscript(path: str) -> UrProgram:
    """Read a URScript program's motion targets, in program order."""
    text = read_program_text(path)
    reader = _Reader(path, text)
    targets: list[ProgramTarget] = []
    seen: dict[int, ProgramTarget] = {}
    tcp: _Value | None = None
    for start, what, data in _events(reader):
        if what == "tcp":
            assert isinstance(data, _Value)
            tcp = data
            continue
        assert isinstance(data, tuple)
        v, seed, user = data
        line, col = position(text, v.at)
        call_line = position(text, start)[0]
        if v.kind in ("computed", "unknown"):
            t = ProgramTarget(f"line {call_line}", path, call_line, col, "computed", {})
            if v.kind == "computed":
                t.note = f"computed at run time: {_short(v.text)}"
                t.extra["kept"] = True
            else:
                t.note = f"value not known: {v.text}"
            targets.append(t)
            continue
        tcp_key = None if tcp is None or tcp.slots is None else \
            tuple(s.value for s in tcp.slots)
        user_key = None if user is None or user.slots is None else \
            tuple(s.value for s in user.slots)
        if v.at in seen:
            t = seen[v.at]
            if t.extra.get("tcp_key") != tcp_key:
                t.note = "used with two different TCPs"
            if t.extra.get("user_key") != user_key:
                t.note = "used in two different frames (pose_trans)"
            continue
        assert v.slots is not None
        if len(v.slots) != 6:
            what = "pose" if v.kind == "pose" else "joint list"
            raise fail(path, text, v.at, f"{what} needs 6 numbers, got {len(v.slots)}")
        keys = POSE_KEYS if v.kind == "pose" else JOINT_KEYS
        name = f"line {line}" if line == call_line else f"line {line} (used line {call_line})"
        t = ProgramTarget(name, path, line, col, v.kind, dict(zip(keys, v.slots, strict=True)))
        t.extra["tcp"] = None if tcp_key is None else np.array(tcp_key)
        t.extra["tcp_key"] = tcp_key
        t.extra["user_key"] = user_key
        if user_key is not None:
            t.extra["user"] = np.array(user_key)
            t.extra["user_at"] = user.at if user is not None else -1
        if tcp is not None and tcp.slots is None and v.kind == "pose":
            t.note = f"the TCP is computed at run time: {_short(tcp.text)}"
        if seed is not None:
            if seed.kind == "joints" and seed.slots is not None and len(seed.slots) == 6:
                t.extra["seed_axes"] = np.array([s.value for s in seed.slots])
            elif v.kind == "pose":
                t.note = f"qnear of get_inverse_kin is not known here: {_short(seed.text)}"
        seen[v.at] = t
        targets.append(t)
    for t in targets:            # a feature that is itself a target would move with it
        if t.extra.get("user_at", -1) in seen and not t.note:
            t.note = ("relative to a pose that is itself a motion target (pose_trans): left "
                      "as it is")
            t.extra["kept"] = True
    return UrProgram({path: text}, targets)


def _short(s: str, n: int = 50) -> str:
    s = " ".join(s.split())
    return s if len(s) <= n else s[:n - 3] + "..."


def pose_matrix(v: Array) -> Array:
    """``p[x, y, z, rx, ry, rz]`` [m, rad] as a 4x4: ``Trans(x, y, z) exp([r]x)``."""
    return homogeneous(exp_so3(np.asarray(v[3:6], dtype=float)), np.asarray(v[:3], dtype=float))


def frames(prog: UrProgram, t: ProgramTarget, fr: Frames) -> tuple[Array, Array]:
    """(the feature of ``pose_trans(feature, pose)`` or the base frame, the TCP set
    before the motion)."""
    tcp, user = t.extra.get("tcp"), t.extra.get("user")
    return (np.eye(4) if user is None else pose_matrix(user),
            np.eye(4) if tcp is None else pose_matrix(tcp))


def pose_of(t: ProgramTarget) -> Array:
    return pose_matrix(t.values(POSE_KEYS))


def pose_values(t: ProgramTarget, T: Array) -> dict[str, float]:
    """x, y, z [m] and the rotation vector of T [rad], the one nearest the target's own
    (``r`` and ``r (1 - 2 pi / |r|)`` are the same rotation)."""
    r = log_so3(T[:3, :3])
    old = t.values(("rx", "ry", "rz"))
    angle = float(np.linalg.norm(r))
    if angle > 1e-12:
        alt = r * (1 - 2 * np.pi / angle)
        if np.linalg.norm(alt - old) < np.linalg.norm(r - old):
            r = alt
    return {"x": T[0, 3], "y": T[1, 3], "z": T[2, 3], "rx": r[0], "ry": r[1], "rz": r[2]}


def config_values(t: ProgramTarget, axes: Array, signs: Array) -> dict[str, float]:
    """URScript states no configuration."""
    return {}
