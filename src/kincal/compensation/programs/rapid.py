"""ABB RAPID modules (``.mod``, ``.modx``, ``.prg``).

What is read (RAPID reference manual syntax):

* data declarations ``[LOCAL|TASK] CONST|PERS|VAR robtarget|jointtarget|tooldata|wobjdata
  name := [...];``: ``robtarget [[x, y, z], [q1, q2, q3, q4], [cf1, cf4, cf6, cfx],
  [eax_a, ..., eax_f]]`` in mm with a unit quaternion (``q1`` = w); ``jointtarget
  [[rax_1, ..., rax_6], [eax ...]]`` in deg; a numeric ``eax_a`` (not ``9E9``) is read as
  well: a 7-axis arm (YuMi IRB 14000 / 14050) carries its axis 7 there, in a jointtarget
  and, as the arm angle the controller keeps, in a robtarget; ``tooldata [robhold,
  [[x, y, z], [q]], load]`` (``robhold`` TRUE: the robot holds the tool); ``wobjdata
  [robhold, ufprog, ufmec, [[x, y, z], [q]] (user frame), [[x, y, z], [q]] (object frame)]``;
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
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kincal.compensation.configuration import abb_configuration
from kincal.compensation.programs.base import (
    Array,
    Frames,
    ProgramError,
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
_DECL_BARE = re.compile(r"\b(?:PERS|VAR)\s+(?:robtarget|jointtarget|tooldata|wobjdata)\s+"
                        r"([A-Za-z]\w*)\s*(?:\{[^}]*\})?\s*;", re.IGNORECASE)
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
    """A RAPID program: every module's text, the targets in declaration and use order,
    the tools and work objects declared with a value (by lower-case name), and the
    minimum decimals per kind of number (:func:`file_digits`)."""

    texts: dict[str, str]
    targets: list[ProgramTarget]
    tools: dict[str, Array]
    wobjs: dict[str, Array]
    digits: dict[str, int] = field(default_factory=dict)
    computed: set[str] = field(default_factory=set)


def _robtarget(path: str, text: str, name: str, node: Any, at: int) -> ProgramTarget:
    if not isinstance(node, list) or len(node) != 4:
        raise fail(path, text, at, "a robtarget is [[x, y, z], [q1, q2, q3, q4], "
                                   "[cf1, cf4, cf6, cfx], [extax]]")
    p = _numbers(path, text, node[0], 3, at, "robtarget position")
    q = _numbers(path, text, node[1], 4, at, "robtarget orientation")
    cf = _numbers(path, text, node[2], 4, at, "robtarget confdata")
    slots = dict(zip(("x", "y", "z", "q1", "q2", "q3", "q4", "cf1", "cf4", "cf6", "cfx"),
                     p + q + cf, strict=True))
    slots.update(_eax_a(node[3]))
    line, col = position(text, p[0].start)
    conf = abb_configuration(*(int(round(s.value)) for s in cf))
    return ProgramTarget(name, path, line, col, "pose", slots, conf)


#: An external axis value at or above this [deg / mm] is RAPID's "not used" (9E9).
_UNUSED_AXIS = 8e9


def _eax_a(extax: Any) -> dict[str, Slot]:
    """``{"eax_a": slot}`` when the first external axis of ``extax`` is a used number."""
    if isinstance(extax, list) and extax and isinstance(extax[0], Slot) \
            and abs(extax[0].value) < _UNUSED_AXIS:
        return {"eax_a": extax[0]}
    return {}


def _jointtarget(path: str, text: str, name: str, node: Any, at: int) -> ProgramTarget:
    if not isinstance(node, list) or len(node) != 2:
        raise fail(path, text, at, "a jointtarget is [[rax_1, ..., rax_6], [extax]]")
    j = _numbers(path, text, node[0], 6, at, "jointtarget robax")
    line, col = position(text, j[0].start)
    slots = dict(zip(JOINT_KEYS, j, strict=True))
    slots.update(_eax_a(node[1]))
    return ProgramTarget(name, path, line, col, "joints", slots)


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


#: Suffixes of RAPID program and system modules.
MODULE_SUFFIXES = (".mod", ".modx", ".sys", ".sysx", ".prg")


def module_files(path: str | Sequence[str]) -> list[str]:
    """The module files of a program given as one file, several files or a folder.

    A folder is a controller backup (``RAPID/TASK1/PROGMOD`` and ``SYSMOD``: the one task
    folder's modules) or a folder of modules (every module below it, sorted).  A backup
    with several tasks (a MultiMove or YuMi system: one robot per task) must be given
    as the one task's folder."""
    paths = [path] if isinstance(path, str) else list(path)
    out: list[str] = []
    for p in paths:
        folder = Path(p)
        if not folder.is_dir():
            out.append(str(p))
            continue
        tasks = sorted({d.parent for d in folder.rglob("*")
                        if d.is_dir() and d.name.upper() in ("PROGMOD", "SYSMOD")})
        if len(tasks) > 1:
            names = ", ".join(str(t.relative_to(folder)) for t in tasks)
            raise ProgramError(f"holds {len(tasks)} RAPID tasks ({names}): give the folder of "
                               "the task of the calibrated robot", source=str(p))
        root = tasks[0] if tasks else folder
        found = sorted(str(f) for f in root.rglob("*")
                       if f.is_file() and f.suffix.lower() in MODULE_SUFFIXES)
        if not found:
            raise ProgramError("no RAPID module (.mod, .modx, .sys, .prg) in this folder",
                               source=str(p))
        out += found
    return out


#: Motion instructions: (number of robtarget arguments, positional index of the tool).
_SIGNATURE = {"movej": (1, 3), "movel": (1, 3), "moveabsj": (1, 3), "movejdo": (1, 3),
              "moveldo": (1, 3), "movejsync": (1, 3), "movelsync": (1, 3), "movec": (2, 4),
              "movecdo": (2, 4), "movecsync": (2, 4), "triggj": (1, 4), "triggl": (1, 4),
              "triggc": (2, 5)}
_CONF = re.compile(r"\bConf([JL])\s*\\\s*(On|Off)\b", re.IGNORECASE)
_RELATIVE = ("offs", "reltool")


def _declarations(path: str, text: str, code: str, prog: RapidProgram,
                  by_name: dict[str, ProgramTarget]) -> None:
    """Pass 1 over one module: its robtargets, jointtargets, tools and work objects."""
    for m in _DECL_BARE.finditer(code):                # declared without a value
        prog.computed.add(m.group(1).lower())
    for m in _DECL.finditer(code):
        kind, name = m.group(2).lower(), m.group(3)
        at = m.end()
        if at >= len(code) or code[at] != "[":
            prog.computed.add(name.lower())           # a value computed by the program
            continue
        node, _ = parse_list(path, text, code, at)
        if kind in ("robtarget", "jointtarget"):
            t = (_robtarget if kind == "robtarget" else _jointtarget)(path, text, name, node,
                                                                       at)
            t.used = False
            prog.targets.append(t)
            by_name[name.lower()] = t
        elif kind == "tooldata":
            if not isinstance(node, list) or len(node) < 2:
                raise fail(path, text, at, "a tooldata is [robhold, [[x, y, z], [q]], load]")
            prog.tools[name.lower()] = (np.full((4, 4), np.nan)      # stationary tool
                                        if str(node[0]).upper() == "FALSE" else
                                        _frame(path, text, node[1], at, "tooldata tframe"))
        else:
            if not isinstance(node, list) or len(node) != 5:
                raise fail(path, text, at, "a wobjdata is [robhold, ufprog, ufmec, uframe, "
                                           "oframe]")
            uf = _frame(path, text, node[3], at, "wobjdata uframe")
            of = _frame(path, text, node[4], at, "wobjdata oframe")
            prog.wobjs[name.lower()] = (np.full((4, 4), np.nan)
                                        if str(node[0]).upper() == "TRUE" else uf @ of)


def _head(arg: str) -> str:
    """The name an argument starts with (after an ``Name :=`` prefix)."""
    a = re.sub(r"^\s*[A-Za-z]\w*\s*:=", "", arg)
    m = re.match(r"\s*([A-Za-z]\w*)", a)
    return m.group(1) if m else ""


_PROC = re.compile(r"^[ \t]*(?:LOCAL[ \t]+)?PROC[ \t]+([A-Za-z]\w*)[^\n]*\n(.*?)^[ \t]*ENDPROC\b",
                   re.IGNORECASE | re.MULTILINE | re.DOTALL)


#: A statement that is a name (and arguments): a procedure call when the name is a PROC.
_CALL = re.compile(r"^[ \t]*([A-Za-z]\w*)[ \t]*(?:;|[ \t\\][^;\n]*;)", re.MULTILINE)


@dataclass
class _Proc:
    """One procedure: its module and the span of its body in the module's text."""

    path: str
    start: int
    end: int


class _Motions:
    """Pass 2: the motion instructions in program order, with the configuration
    monitoring (``ConfJ`` / ``ConfL``) they run under.

    Program order is followed statically: from ``main``, each procedure's motions and
    configuration switches in textual order, a call of a procedure (a statement that is
    its name) walked where it stands (branches and loops are not evaluated; a procedure
    already being walked is not entered again); then the procedures no walk reached, and
    code outside procedures, in module order."""

    def __init__(self, prog: RapidProgram, by_name: dict[str, ProgramTarget],
                 codes: dict[str, str]) -> None:
        self.prog = prog
        self.by_name = by_name
        self.codes = codes
        self.monitor = {"j": True, "l": True}          # On after PP to main
        self.prev: ProgramTarget | None = None
        self.seen_missing: dict[str, ProgramTarget] = {}
        self.uses: dict[int, list[tuple[str, ProgramTarget | None]]] = {}
        self.procs: dict[str, _Proc] = {}
        for f, code in codes.items():
            for m in _PROC.finditer(code):
                self.procs.setdefault(m.group(1).lower(), _Proc(f, m.start(2), m.end(2)))
        self.walked: set[str] = set()

    def run(self) -> None:
        """Walk the program: ``main`` first, then whatever it did not reach."""
        if "main" in self.procs:
            self._walk("main", [])
        for name in self.procs:
            if name not in self.walked:
                self._walk(name, [])
        for f, code in self.codes.items():             # statements outside any procedure
            inside = [(p.start, p.end) for p in self.procs.values() if p.path == f]
            self._span(f, 0, len(code), [], inside)

    def _walk(self, name: str, stack: list[str]) -> None:
        proc = self.procs[name]
        self.walked.add(name)
        self._span(proc.path, proc.start, proc.end, stack + [name], [])

    def _span(self, path: str, start: int, end: int, stack: list[str],
              skip: list[tuple[int, int]]) -> None:
        code, text = self.codes[path], self.prog.texts[path]
        events = [(m.start(), "conf", m) for m in _CONF.finditer(code, start, end)]
        events += [(m.start(), "move", m) for m in _MOVE.finditer(code, start, end)]
        events += [(m.start(), "call", m) for m in _CALL.finditer(code, start, end)
                   if m.group(1).lower() in self.procs]
        for at, what, m in sorted(events, key=lambda e: e[0]):
            if any(a <= at < b for a, b in skip):
                continue
            if what == "conf":
                self.monitor[m.group(1).lower()] = m.group(2).lower() == "on"
            elif what == "call":
                if m.group(1).lower() not in stack:
                    self._walk(m.group(1).lower(), stack)
            elif m.group(1).lower() in _SIGNATURE:
                self._move(path, text, code, m)

    def _move(self, path: str, text: str, code: str, m: re.Match[str]) -> None:
        instr = m.group(1).lower()
        n_targets, tool_at = _SIGNATURE[instr]
        args, _ = _split_args(code, m.end())
        positional = [(off, a) for off, a in args if not a.lstrip().startswith("\\")]
        wobj = "wobj0"
        for _, a in args:
            w = re.search(r"\\WObj\s*:=\s*([A-Za-z]\w*)", a, re.IGNORECASE)
            if w:
                wobj = w.group(1)
        tool = _head(positional[tool_at][1]) if len(positional) > tool_at else ""
        key = (tool or "?", wobj)
        kind = "j" if instr in ("movej", "movejdo", "movejsync", "triggj") else "l"
        # "" when the configuration is monitored, else the instruction that switched it off
        unmonitored = "" if instr == "moveabsj" or self.monitor[kind] else f"Conf{kind.upper()}"
        for off, a in positional[:n_targets]:
            stripped = a.lstrip()
            at = off + len(a) - len(stripped)
            t = self._target(path, text, code, instr, stripped, at)
            if t is None:
                self.prev = None
                continue
            if t.slots:
                if t.used and (str(t.tool_key).lower(), str(t.base_key).lower()) != \
                        (key[0].lower(), key[1].lower()):
                    t.note = (f"used with {t.tool_key}/{t.base_key} and with "
                              f"{key[0]}/{key[1]}")
                t.tool_key, t.base_key = key
            t.used = True
            self.uses.setdefault(id(t), []).append((unmonitored, self.prev))
            self.prev = t

    def _target(self, path: str, text: str, code: str, instr: str, arg: str, at: int
                ) -> ProgramTarget | None:
        """The target an argument names or writes (None: nothing the filter follows)."""
        ln, col = position(text, at)
        if arg.startswith("["):
            node, _ = parse_list(path, text, code, at)
            t = (_jointtarget if instr == "moveabsj" else _robtarget)(
                path, text, f"line {ln}", node, at)
            t.used = False
            self.prog.targets.append(t)
            return t
        head = re.match(r"([A-Za-z]\w*)\s*(\(|\\|$)", arg.rstrip())
        if head is None:
            return None
        name = head.group(1)
        if head.group(2) == "(":
            base = re.match(r"[A-Za-z]\w*\s*\(\s*([A-Za-z]\w*)", arg)
            ref = base.group(1) if base else "?"
            if name.lower() in _RELATIVE:
                note = (f"relative: {name}({ref}, ...) is computed at run time from {ref}, "
                        "and follows its filtered value")
            else:
                note = f"computed at run time by {name}(...): not filtered"
            return self._listed(path, ln, col, f"{name}({ref}...) line {ln}", note)
        point = self.by_name.get(name.lower())
        if point is not None:
            return point
        if name.lower() in self.prog.computed:
            note = (f"{name} is assigned at run time (declared without a value): "
                    "not filtered")
        else:
            note = (f"{name} is declared in no module read ({self._files()}): give its "
                    "module too")
        return self._listed(path, ln, col, name, note)

    def _listed(self, path: str, line: int, col: int, name: str, note: str) -> ProgramTarget:
        known = self.seen_missing.get(name.lower())
        if known is not None:
            return known
        t = ProgramTarget(name, path, line, col, "pose", {}, note=note)
        self.prog.targets.append(t)
        self.seen_missing[name.lower()] = t
        return t

    def _files(self) -> str:
        return ", ".join(Path(f).name for f in self.prog.texts)

    def finish(self) -> None:
        """Targets reached only with configuration monitoring off: no configuration
        (the controller takes the solution nearest to the previous position)."""
        for t in self.prog.targets:
            uses = self.uses.get(id(t), [])
            if t.kind != "pose" or not t.slots or not uses or any(not off for off, _ in uses):
                continue
            t.config = None
            t.extra["after"] = uses[0][1]
            t.extra["warning"] = f"{uses[0][0]}\\Off: branch nearest the previous target"


def file_digits(targets: Sequence[ProgramTarget]) -> dict[str, int]:
    """Minimum decimals per kind of number: the finest the program writes (RAPID drops
    trailing zeros, so one number's decimals say little), at least 2 for mm and deg and
    6 for a quaternion, so a correction is not rounded away."""
    finest = {"pos": 2, "quat": 6, "joint": 2}
    for t in targets:
        for k, slot in t.slots.items():
            kind = ("pos" if k in ("x", "y", "z") else "quat" if k.startswith("q") else
                    "joint" if k.startswith("j") else "")
            if kind:
                finest[kind] = max(finest[kind], slot.style.decimals)
    return finest


def read_rapid(path: str | Sequence[str]) -> RapidProgram:
    """Read a RAPID program: one module, several modules, or a folder of them
    (:func:`module_files`).  Declarations are shared by all modules (a tool in
    ``CalibData.mod`` serves a motion in ``MainModule.mod``); motions are followed in
    module and textual order."""
    files = module_files(path)
    prog = RapidProgram({}, [], {"tool0": np.eye(4)}, {"wobj0": np.eye(4)})
    codes: dict[str, str] = {}
    by_name: dict[str, ProgramTarget] = {}
    for f in files:
        text = read_program_text(f)
        prog.texts[f] = text
        codes[f] = code_of(text)
        _declarations(f, text, codes[f], prog, by_name)
    motions = _Motions(prog, by_name, codes)
    motions.run()
    motions.finish()
    prog.digits = file_digits(prog.targets)
    return prog


def frames(prog: RapidProgram, t: ProgramTarget, fr: Frames) -> tuple[Array, Array]:
    """(work object, tool) of a target [m]: declared in a module read, else from
    ``--frames`` by name (``tool: {tGripper: ...}``, ``base: {wTable: ...}``, the work
    object's user frame times object frame).  An unknown one, a held work object or a
    stationary tool is refused for this target."""
    from kincal.errors import KincalError

    where = f"{t.name} ({Path(t.file).name}:{t.line})"
    found: list[Array] = []
    for which, table, key in (("tool", prog.tools, t.tool_key),
                              ("work object", prog.wobjs, t.base_key)):
        k = str(key).lower()
        named = {n.lower(): v for n, v in (fr.base if which == "work object"
                                            else fr.tool).items()}
        value = table.get(k, named.get(k))
        if value is None:
            files = ", ".join(Path(f).name for f in prog.texts)
            raise KincalError(f"{where}: {which} {key!r} is declared in no module read "
                              f"({files}) nor in --frames: give the module that declares it "
                              "(RobotStudio: CalibData.mod) or --frames")
        found.append(value)
    tool, wobj = found
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


def digits(prog: RapidProgram, key: str) -> int:
    """Minimum decimals of a rewritten number: the program's own (:func:`file_digits`),
    none for confdata."""
    if key.startswith("cf"):
        return 0
    kind = "pos" if key in ("x", "y", "z") else "quat" if key.startswith("q") else "joint"
    return prog.digits.get(kind, 4)


def config_values(t: ProgramTarget, axes: Array, signs: Array) -> dict[str, float]:
    """confdata of the filtered joints: quadrants of axes 1, 4, 6 (deg) and cfx."""
    out = {f"cf{k + 1}": float(np.floor(axes[k] / 90.0)) for k in (0, 3, 5)}
    if np.all(signs != 0):
        out["cfx"] = float(4 * int(signs[0] < 0) + 2 * int(signs[1] < 0) + int(signs[2] < 0))
    return out
