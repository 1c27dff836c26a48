"""ABB RAPID modules (``.mod``, ``.modx``, ``.prg``).

What is read (RAPID reference manual syntax):

* data declarations ``[LOCAL|TASK] CONST|PERS|VAR robtarget|jointtarget|tooldata|wobjdata
  name := [...];``: ``robtarget [[x, y, z], [q1, q2, q3, q4], [cf1, cf4, cf6, cfx],
  [eax_a, ..., eax_f]]`` in mm with a unit quaternion (``q1`` = w); ``jointtarget
  [[rax_1, ..., rax_6], [eax ...]]`` in deg; ``tooldata [robhold, [[x, y, z], [q]], load]``
  (``robhold`` TRUE: the robot holds the tool); ``wobjdata [robhold, ufprog, ufmec,
  [[x, y, z], [q]] (user frame), [[x, y, z], [q]] (object frame)]``;
* motion instructions ``MoveJ``, ``MoveL``, ``MoveC`` (a circle point and an end point),
  ``MoveAbsJ``, the ``...DO``/``...Sync`` and ``Trigg`` variants, with a named or an inline
  target, the tool argument and ``\\WObj:=``; ``tool0`` and ``wobj0`` are the flange and
  the base frame.

``!`` starts a comment; statements end with ``;`` and may span lines.  A robtarget's
pose is ``T_base = uframe * oframe * target`` and the flange is ``T_base * tool^-1``.
A target used with two different tool/work-object pairs is not filtered.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from kincal.compensation.configuration import abb_configuration
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
from kincal.compensation.programs.numbers import NUMBER
from kincal.spatial import homogeneous, quat_to_matrix

JOINT_KEYS = ("j1", "j2", "j3", "j4", "j5", "j6")
_DECL = re.compile(r"(?:\b(?:LOCAL|TASK)\s+)?\b(CONST|PERS|VAR)\s+(robtarget|jointtarget|tooldata|"
                   r"wobjdata)\s+([A-Za-z]\w*)\s*:=\s*", re.IGNORECASE)
_MOVE = re.compile(r"\b(MoveJ|MoveL|MoveC|MoveAbsJ|MoveJDO|MoveLDO|MoveCDO|MoveJSync|MoveLSync|"
                   r"MoveCSync|TriggJ|TriggL|TriggC|MoveExtJ)\b\s*", re.IGNORECASE)


def code_of(text: str) -> str:
    """``text`` with comments (``!`` to the end of the line, outside strings) blanked."""
    out = list(text)
    inside = False
    comment = False
    for i, ch in enumerate(text):
        if ch == "\n":
            inside = comment = False
            continue
        if comment:
            if ch != "\r":
                out[i] = " "
            continue
        if ch == '"':
            inside = not inside
        elif ch == "!" and not inside:
            comment = True
            out[i] = " "
    return "".join(out)


def parse_list(path: str, text: str, code: str, start: int) -> tuple[Any, int]:
    """The bracketed aggregate at ``code[start] == "["``: nested lists of :class:`Slot`,
    strings and names; and the offset after its ``]``."""
    assert code[start] == "["
    items: list[Any] = []
    pos = start + 1
    while True:
        while pos < len(code) and code[pos] in " \t\r\n":
            pos += 1
        if pos >= len(code):
            raise fail(path, text, start, "'[' is not closed")
        ch = code[pos]
        if ch == "]" and not items:
            return items, pos + 1
        if ch == "[":
            sub, pos = parse_list(path, text, code, pos)
            items.append(sub)
        elif ch == '"':
            end = code.find('"', pos + 1)
            if end < 0:
                raise fail(path, text, pos, "string is not closed")
            items.append(code[pos:end + 1])
            pos = end + 1
        else:
            m = NUMBER.match(code, pos)
            if m is not None:
                items.append(number_slot(path, text, m.start(), m.end(), "value"))
                pos = m.end()
            else:
                w = re.match(r"[A-Za-z_]\w*", code[pos:])
                if w is None:
                    raise fail(path, text, pos, f"unexpected {ch!r} in an aggregate")
                items.append(w.group(0))
                pos += w.end()
        while pos < len(code) and code[pos] in " \t\r\n":
            pos += 1
        if pos < len(code) and code[pos] == ",":
            pos += 1
            continue
        if pos < len(code) and code[pos] == "]":
            return items, pos + 1
        raise fail(path, text, pos, "expected ',' or ']' in an aggregate")


def _numbers(path: str, text: str, node: Any, count: int, at: int, what: str) -> list[Slot]:
    if not isinstance(node, list) or len(node) != count or \
            not all(isinstance(v, Slot) for v in node):
        raise fail(path, text, at, f"{what} must be [{count} numbers]")
    return node


def _frame(path: str, text: str, node: Any, at: int, what: str) -> Array:
    if not isinstance(node, list) or len(node) != 2:
        raise fail(path, text, at, f"{what} must be [[x, y, z], [q1, q2, q3, q4]]")
    p = [s.value for s in _numbers(path, text, node[0], 3, at, f"{what} position")]
    q = [s.value for s in _numbers(path, text, node[1], 4, at, f"{what} orientation")]
    return homogeneous(quat_to_matrix(np.array(q)), np.array(p) * 1e-3)


def matrix_to_quat(R: Array) -> Array:
    """``[w, x, y, z]`` with ``w >= 0`` of a rotation matrix (Shepperd's method)."""
    t = np.trace(R)
    k = int(np.argmax([t, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        s = 2 * np.sqrt(1 + t)
        q = [s / 4, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif k == 1:
        s = 2 * np.sqrt(1 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, s / 4, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif k == 2:
        s = 2 * np.sqrt(1 - R[0, 0] + R[1, 1] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, s / 4, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2 * np.sqrt(1 - R[0, 0] - R[1, 1] + R[2, 2])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, s / 4]
    qq = np.array(q)
    return qq if qq[0] >= 0 else -qq


@dataclass
class RapidProgram:
    texts: dict[str, str]
    targets: list[ProgramTarget]
    tools: dict[str, Array]
    wobjs: dict[str, Array]


def _robtarget(path: str, text: str, name: str, node: Any, at: int) -> ProgramTarget:
    if not isinstance(node, list) or len(node) != 4:
        raise fail(path, text, at, "a robtarget is [[x, y, z], [q1, q2, q3, q4], "
                                   "[cf1, cf4, cf6, cfx], [extax]]")
    p = _numbers(path, text, node[0], 3, at, "robtarget position")
    q = _numbers(path, text, node[1], 4, at, "robtarget orientation")
    cf = _numbers(path, text, node[2], 4, at, "robtarget confdata")
    slots = dict(zip(("x", "y", "z", "q1", "q2", "q3", "q4", "cf1", "cf4", "cf6", "cfx"),
                     p + q + cf, strict=True))
    line, col = position(text, p[0].start)
    conf = abb_configuration(*(int(round(s.value)) for s in cf))
    return ProgramTarget(name, path, line, col, "pose", slots, conf)


def _jointtarget(path: str, text: str, name: str, node: Any, at: int) -> ProgramTarget:
    if not isinstance(node, list) or len(node) != 2:
        raise fail(path, text, at, "a jointtarget is [[rax_1, ..., rax_6], [extax]]")
    j = _numbers(path, text, node[0], 6, at, "jointtarget robax")
    line, col = position(text, j[0].start)
    return ProgramTarget(name, path, line, col, "joints", dict(zip(JOINT_KEYS, j, strict=True)))


def _split_args(code: str, start: int) -> tuple[list[tuple[int, str]], int]:
    """Arguments of an instruction from ``start`` to its ``;``, split at depth-0 commas."""
    args: list[tuple[int, str]] = []
    depth = 0
    begin = start
    i = start
    inside = False
    while i < len(code):
        ch = code[i]
        if ch == '"':
            inside = not inside
        elif not inside:
            if ch in "[(":
                depth += 1
            elif ch in "])":
                depth -= 1
            elif ch == "," and depth == 0:
                args.append((begin, code[begin:i]))
                begin = i + 1
            elif ch == ";" and depth == 0:
                args.append((begin, code[begin:i]))
                return args, i + 1
        i += 1
    args.append((begin, code[begin:i]))
    return args, i


def read_rapid(path: str) -> RapidProgram:
    """Read a RAPID module: its targets, tools and work objects."""
    text = read_program_text(path)
    code = code_of(text)
    targets: list[ProgramTarget] = []
    by_name: dict[str, ProgramTarget] = {}
    tools: dict[str, Array] = {"tool0": np.eye(4)}
    wobjs: dict[str, Array] = {"wobj0": np.eye(4)}
    for m in _DECL.finditer(code):
        kind, name = m.group(2).lower(), m.group(3)
        at = m.end()
        if at >= len(code) or code[at] != "[":
            continue                                   # a value computed by a function
        node, _ = parse_list(path, text, code, at)
        if kind == "robtarget":
            t = _robtarget(path, text, name, node, at)
            t.used = False
            targets.append(t)
            by_name[name.lower()] = t
        elif kind == "jointtarget":
            t = _jointtarget(path, text, name, node, at)
            t.used = False
            targets.append(t)
            by_name[name.lower()] = t
        elif kind == "tooldata":
            if not isinstance(node, list) or len(node) < 2:
                raise fail(path, text, at, "a tooldata is [robhold, [[x, y, z], [q]], load]")
            if str(node[0]).upper() == "FALSE":
                tools[name.lower()] = np.full((4, 4), np.nan)   # stationary tool
            else:
                tools[name.lower()] = _frame(path, text, node[1], at, "tooldata tframe")
        else:
            if not isinstance(node, list) or len(node) != 5:
                raise fail(path, text, at, "a wobjdata is [robhold, ufprog, ufmec, uframe, "
                                           "oframe]")
            uf = _frame(path, text, node[3], at, "wobjdata uframe")
            of = _frame(path, text, node[4], at, "wobjdata oframe")
            wobjs[name.lower()] = (np.full((4, 4), np.nan) if str(node[0]).upper() == "TRUE"
                                   else uf @ of)
    for m in _MOVE.finditer(code):
        instr = m.group(1).lower()
        args, _ = _split_args(code, m.end())
        n_targets = 2 if instr in ("movec", "movecdo", "movecsync", "triggc") else 1
        wobj = "wobj0"
        tool = None
        for _, a in args:
            w = re.search(r"\\WObj\s*:=\s*([A-Za-z]\w*)", a, re.IGNORECASE)
            if w:
                wobj = w.group(1).lower()
        for _, a in args[n_targets:]:
            head = re.match(r"\s*([A-Za-z]\w*)", a)
            if head and head.group(1).lower() in tools:
                tool = head.group(1).lower()
                break
        for off, a in args[:n_targets]:
            stripped = a.lstrip()
            at = off + len(a) - len(stripped)
            if stripped.startswith("["):
                node, _ = parse_list(path, text, code, at)
                ln = position(text, at)[0]
                t = (_jointtarget if instr == "moveabsj" else _robtarget)(
                    path, text, f"line {ln}", node, at)
                t.tool_key, t.base_key = tool or "tool0", wobj
                targets.append(t)
                continue
            head = re.match(r"([A-Za-z]\w*)\s*(\\.*)?$", stripped.rstrip())
            if head is None:
                continue                                # Offs(...), RelTool(...): computed
            point = by_name.get(head.group(1).lower())
            if point is None:
                continue
            key = (tool or "tool0", wobj)
            if point.used and (point.tool_key, point.base_key) != key:
                point.note = (f"used with {point.tool_key}/{point.base_key} and with "
                              f"{key[0]}/{key[1]}")
            point.used = True
            point.tool_key, point.base_key = key
    return RapidProgram({path: text}, targets, tools, wobjs)


def frames(prog: RapidProgram, t: ProgramTarget, fr: Frames) -> tuple[Array, Array]:
    """(work object, tool) of a target [m]; a held work object or stationary tool is refused."""
    from kincal.errors import KincalError

    tool = prog.tools.get(str(t.tool_key).lower())
    wobj = prog.wobjs.get(str(t.base_key).lower())
    where = f"{t.name} ({t.file}:{t.line})"
    if tool is None or wobj is None:
        raise KincalError(f"{where}: unknown tool {t.tool_key!r} or work object {t.base_key!r}")
    if np.isnan(tool).any() or np.isnan(wobj).any():
        raise KincalError(f"{where}: a stationary tool or a robot-held work object is not "
                          "supported")
    return wobj, tool


def pose_of(t: ProgramTarget) -> Array:
    """The robtarget's pose in its work object [m]."""
    p = t.values(("x", "y", "z")) * 1e-3
    return homogeneous(quat_to_matrix(t.values(("q1", "q2", "q3", "q4"))), p)


def pose_values(t: ProgramTarget, T: Array) -> dict[str, float]:
    """x, y, z [mm] and the quaternion of T, with the sign of the target's own."""
    q = matrix_to_quat(T[:3, :3])
    if float(np.dot(q, t.values(("q1", "q2", "q3", "q4")))) < 0:
        q = -q
    return {"x": T[0, 3] * 1e3, "y": T[1, 3] * 1e3, "z": T[2, 3] * 1e3,
            "q1": q[0], "q2": q[1], "q3": q[2], "q4": q[3]}


def digits(key: str) -> int:
    """Minimum decimals: 4 for mm and deg, 9 for quaternion components, none for confdata."""
    return 0 if key.startswith("cf") else 9 if key.startswith("q") else 4


def config_values(t: ProgramTarget, axes: Array, signs: Array) -> dict[str, float]:
    """confdata of the filtered joints: quadrants of axes 1, 4, 6 (deg) and cfx."""
    out = {f"cf{k + 1}": float(np.floor(axes[k] / 90.0)) for k in (0, 3, 5)}
    if np.all(signs != 0):
        out["cfx"] = float(4 * int(signs[0] < 0) + 2 * int(signs[1] < 0) + int(signs[2] < 0))
    return out
