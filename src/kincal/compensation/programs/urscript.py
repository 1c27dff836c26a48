"""Universal Robots URScript (``.script``).

What is read (URScript manual syntax): motion calls ``movej``, ``movel``, ``movep``,
``movec`` (a via pose and an end pose) whose target is a pose literal
``p[x, y, z, rx, ry, rz]`` (m; rotation vector, rad), a joint list ``[q1, ..., q6]``
(rad, ``movej``), or a variable assigned one of them (``global wp = p[...]``);
``set_tcp(p[...])`` sets the tool for the motions after it, in file order.  ``#``
starts a comment.  Poses are in the robot's base frame.  URScript states no
configuration: the controller takes the solution nearest the current joints, so each
Cartesian target is solved from the joint target before it.
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
    number_slot,
    position,
    read_program_text,
)
from kincal.spatial import exp_so3, homogeneous, log_so3

JOINT_KEYS = ("j1", "j2", "j3", "j4", "j5", "j6")
POSE_KEYS = ("x", "y", "z", "rx", "ry", "rz")
_MOVE = re.compile(r"\b(movej|movel|movep|movec)\s*\(")
_ASSIGN = re.compile(r"(?:\b(?:global|local)\s+)?\b([A-Za-z_]\w*)\s*=\s*(p?\[)")
_TCP = re.compile(r"\bset_tcp\s*\(\s*p\[")


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


def _list(path: str, text: str, code: str, start: int, count: int, what: str) -> tuple[list[Slot],
                                                                                        int]:
    """The numbers of ``[a, b, ...]`` starting at ``code[start] == "["``."""
    end = code.find("]", start)
    if end < 0:
        raise fail(path, text, start, f"{what}: '[' is not closed")
    slots = []
    pos = start + 1
    for part in code[start + 1:end].split(","):
        slots.append(number_slot(path, text, pos, pos + len(part), what))
        pos += len(part) + 1
    if len(slots) != count:
        raise fail(path, text, start, f"{what} needs {count} numbers, got {len(slots)}")
    return slots, end + 1


@dataclass
class UrProgram:
    texts: dict[str, str]
    targets: list[ProgramTarget]


def _args(code: str, start: int) -> list[tuple[int, str]]:
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


def read_urscript(path: str) -> UrProgram:
    """Read a URScript program's motion targets, in file order."""
    text = read_program_text(path)
    code = code_of(text)
    events: list[tuple[int, str, list[Slot] | tuple[int, str]]] = []
    variables: dict[str, tuple[int, str]] = {}
    for m in _ASSIGN.finditer(code):
        variables[m.group(1)] = (m.start(2), m.group(2))
    for m in _TCP.finditer(code):
        slots, _ = _list(path, text, code, m.end() - 1, 6, "set_tcp pose")
        events.append((m.start(), "tcp", slots))
    for m in _MOVE.finditer(code):
        n = 2 if m.group(1) == "movec" else 1
        for off, a in _args(code, m.end())[:n]:
            s = a.strip()
            at = off + len(a) - len(a.lstrip())
            if s.startswith("p["):
                events.append((m.start(), "pose", (at + 1, m.group(1))))
            elif s.startswith("["):
                events.append((m.start(), "joints", (at, m.group(1))))
            elif re.fullmatch(r"[A-Za-z_]\w*", s) and s in variables:
                vat, kind = variables[s]
                events.append((m.start(), "pose" if kind == "p[" else "joints", (vat + (
                    1 if kind == "p[" else 0), m.group(1))))
    events.sort(key=lambda e: e[0])
    targets: list[ProgramTarget] = []
    seen: dict[int, ProgramTarget] = {}
    tcp: list[Slot] | None = None
    for _, kind, data in events:
        if isinstance(data, list):          # "tcp": the TCP's slots
            tcp = data
            continue
        at, instr = data
        if at in seen:
            t = seen[at]
            key = None if tcp is None else tuple(s.value for s in tcp)
            if t.extra.get("tcp_key") != key:
                t.note = "used with two different TCPs"
            targets.append(t)
            continue
        line, col = position(text, at)
        if kind == "pose":
            slots, _ = _list(path, text, code, at, 6, "pose")
            t = ProgramTarget(f"line {line}", path, line, col, "pose",
                              dict(zip(POSE_KEYS, slots, strict=True)))
        else:
            slots, _ = _list(path, text, code, at, 6, "joint list")
            t = ProgramTarget(f"line {line}", path, line, col, "joints",
                              dict(zip(JOINT_KEYS, slots, strict=True)))
        t.extra["tcp"] = None if tcp is None else np.array([s.value for s in tcp])
        t.extra["tcp_key"] = None if tcp is None else tuple(s.value for s in tcp)
        seen[at] = t
        targets.append(t)
    unique: list[ProgramTarget] = []
    ids: set[int] = set()
    for t in targets:
        if id(t) not in ids:
            ids.add(id(t))
            unique.append(t)
    return UrProgram({path: text}, unique)


def pose_matrix(v: Array) -> Array:
    """``p[x, y, z, rx, ry, rz]`` [m, rad] as a 4x4: ``Trans(x, y, z) exp([r]x)``."""
    return homogeneous(exp_so3(np.asarray(v[3:6], dtype=float)), np.asarray(v[:3], dtype=float))


def frames(prog: UrProgram, t: ProgramTarget, fr: Frames) -> tuple[Array, Array]:
    """(base frame = identity, the TCP set before the motion)."""
    tcp = t.extra.get("tcp")
    return np.eye(4), (np.eye(4) if tcp is None else pose_matrix(tcp))


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
