"""FANUC TP programs in ASCII form (``.ls``).

What is read (FANUC ASCII program syntax): the ``/POS`` section's points
``P[n]{ GP1: UF : u, UT : t, CONFIG : 'N U T, 0, 0, 0', X = ... mm, Y = ... mm,
Z = ... mm, W = ... deg, P = ... deg, R = ... deg };`` (``R = Rz(R) Ry(P) Rx(W)``, fixed
X-Y-Z angles; ``P[n:"comment"]`` names too) and joint points ``J1= ... deg`` ... ``J6``;
other motion groups (``GP2:`` ...) stay as they are.  A point is used when the ``/MN``
section names it (``J P[1] ...``, ``L P[2:"pick"] ...``, ``C P[3] P[4] ...``).  ``UF``
and ``UT`` number the user and tool frames (``--frames``; 0 is the world frame and
the faceplate).  Numbers are right-aligned in their fields; a rewritten one keeps the
alignment.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from kincal.compensation.configuration import Configuration, fanuc_configuration
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

JOINT_KEYS = ("j1", "j2", "j3", "j4", "j5", "j6")
_POINT = re.compile(r"^P\[(\d+)(?:\s*:\s*\"([^\"]*)\")?\]\s*\{", re.MULTILINE)
_GROUP = re.compile(r"\bGP(\d+)\s*:")
_CART = re.compile(r"\b([XYZWPR])\s*=\s*(\S+)\s*(mm|deg)\b")
_JOINT = re.compile(r"\bJ([1-9])\s*=\s*(\S+)\s*(mm|deg)\b")
_UF = re.compile(r"\bUF\s*:\s*(\w+)")
_UT = re.compile(r"\bUT\s*:\s*(\w+)")
#: The configuration string: ``CONFIG`` (English), ``KONFIG`` (German controllers); any
#: keyword before the one quoted field of a group is read as it.
_CONFIG = re.compile(r"\b([A-Z]+)\s*:\s*'([^']*)'")
#: Another representation of the position (``RX = ... mm`` ... ``RR = ... deg``).
_OTHER_REPR = re.compile(r"\bR[XYZWPR]\s*=")
#: Extended axes in the robot's own group (``E1= ... mm``).
_EXTENDED = re.compile(r"\bE([1-9])\s*=")
_UNTAUGHT = re.compile(r"=\s*\*+")
_USE = re.compile(r"(?<![A-Z])P\[(\d+)")


@dataclass
class LsProgram:
    texts: dict[str, str]
    targets: list[ProgramTarget]


def _section(text: str, name: str) -> tuple[int, int]:
    m = re.search(rf"^/{name}\b[^\n]*\n", text, re.MULTILINE)
    if m is None:
        return -1, -1
    nxt = re.compile(r"^/[A-Z]+", re.MULTILINE).search(text, m.end())
    return m.end(), (nxt.start() if nxt else len(text))


def _used_points(text: str) -> set[int]:
    """Point numbers the ``/MN`` section's instructions name (comment lines ``!`` and
    lines commented out with ``//`` skipped)."""
    mn0, mn1 = _section(text, "MN")
    used: set[int] = set()
    if mn0 >= 0:
        for mn_line in text[mn0:mn1].splitlines():
            if re.match(r"\s*\d*:\s*//", mn_line):
                continue
            code = (mn_line.split("!", 1)[0] if re.match(r"\s*\d*:\s*!", mn_line)
                    else mn_line)
            used |= {int(n) for n in _USE.findall(code)}
    return used


def _not_filterable(chunk: str) -> str:
    """Why a GP1 group cannot be filtered (``""``: it can)."""
    uf, ut = _UF.search(chunk), _UT.search(chunk)
    if (uf is not None and uf.group(1) == "F") or (ut is not None and ut.group(1) == "F") \
            or _UNTAUGHT.search(chunk):
        return ("not taught: the point has no position yet (UF : F, UT : F, "
                "X = ********); the controller stops at a motion to it")
    if _OTHER_REPR.search(chunk):
        return ("a position in the RX ... RR representation: kincal reads only X ... R "
                "and J1 ... J6 points")
    ext = _EXTENDED.search(chunk)
    if ext is not None and _CART.search(chunk):
        return (f"the robot's group carries extended axis E{ext.group(1)}: an integrated "
                "axis moves the robot, which kincal does not model")
    return ""


def _configuration(path: str, text: str, name: str, start: int, chunk: str,
                   slots: dict[str, Slot]) -> Configuration | None:
    """The point's ``CONFIG`` / ``KONFIG`` string as a configuration; its turn numbers
    become slots (``turn1``, ``turn4``, ``turn6``).  An empty string asks for none."""
    cf = _CONFIG.search(chunk)
    if cf is None or not cf.group(2).strip():
        return None
    parts = [p.strip() for p in cf.group(2).split(",")]
    try:
        turns = [int(p) for p in parts[1:4]]
    except ValueError:
        turns = []
    if len(parts) != 4 or len(turns) != 3:
        raise fail(path, text, start + cf.start(2),
                   f"{name}: {cf.group(1)} must be 'F U T, t1, t4, t6', got {cf.group(2)!r}")
    base = start + cf.start(2)
    for key, nm in zip(("turn1", "turn4", "turn6"),
                       list(re.finditer(r"[+-]?\d+", cf.group(2)))[-3:], strict=True):
        slots[key] = number_slot(path, text, base + nm.start(), base + nm.end(),
                                 f"{name} {cf.group(1)}")
    return fanuc_configuration(parts[0], (turns[0], turns[1], turns[2]))


def _point(path: str, text: str, m: re.Match[str], p1: int) -> ProgramTarget:
    """One ``P[n]{ ... };`` of the ``/POS`` section (its GP1 group)."""
    end = text.find("};", m.end(), p1)
    if end < 0:
        raise fail(path, text, m.start(), f"point P[{m.group(1)}] is not closed with '}};'")
    groups = list(_GROUP.finditer(text, m.end(), end))
    g1 = next((g for g in groups if g.group(1) == "1"), None)
    if g1 is None:
        raise fail(path, text, m.start(), f"point P[{m.group(1)}] has no GP1 group")
    nxt = next((g.start() for g in groups if g.start() > g1.start()), end)
    seg = (g1.end(), nxt)
    name = f"P[{m.group(1)}" + (f':"{m.group(2)}"]' if m.group(2) is not None else "]")
    chunk = text[seg[0]:seg[1]]
    why = _not_filterable(chunk)
    if why:
        line, col = position(text, m.start())
        return ProgramTarget(name, path, line, col, "pose", {}, note=why)
    uf, ut = _UF.search(chunk), _UT.search(chunk)
    if uf is None or ut is None:
        raise fail(path, text, g1.start(), f"{name}: GP1 needs 'UF : n, UT : n'")
    cart = {c.group(1): c for c in _CART.finditer(chunk)}
    joints = {c.group(1): c for c in _JOINT.finditer(chunk)}
    if cart:
        missing = [k for k in "XYZWPR" if k not in cart]
        if missing:
            raise fail(path, text, g1.start(), f"{name}: missing {', '.join(missing)}")
        slots = {k.lower(): number_slot(path, text, seg[0] + c.start(2), seg[0] + c.end(2),
                                        f"{name} {k}") for k, c in cart.items()}
        conf = _configuration(path, text, name, seg[0], chunk, slots)
        line, col = position(text, min(s.start for s in slots.values()))
        return ProgramTarget(name, path, line, col, "pose", slots, conf, ut.group(1),
                             uf.group(1))
    if joints:
        slots = {f"j{k}": number_slot(path, text, seg[0] + c.start(2), seg[0] + c.end(2),
                                      f"{name} J{k}") for k, c in joints.items()}
        if len(slots) < 6:
            raise fail(path, text, g1.start(), f"{name}: needs J1 ... J6")
        line, col = position(text, min(s.start for s in slots.values()))
        return ProgramTarget(name, path, line, col, "joints",
                             {k: slots[k] for k in JOINT_KEYS}, None, ut.group(1), uf.group(1))
    raise fail(path, text, g1.start(), f"{name}: GP1 has neither X ... R nor J1 ... J6")


def read_ls(path: str) -> LsProgram:
    """Read a ``.ls`` program's points (group 1) and which of them ``/MN`` uses.

    A point that cannot be filtered (not taught, another position representation,
    extended axes in the robot's group) is read with its reason as ``note``."""
    text = read_program_text(path)
    used = _used_points(text)
    p0, p1 = _section(text, "POS")
    targets: list[ProgramTarget] = []
    if p0 < 0:
        return LsProgram({path: text}, targets)
    for m in _POINT.finditer(text, p0, p1):
        t = _point(path, text, m, p1)
        t.used = int(m.group(1)) in used
        targets.append(t)
    return LsProgram({path: text}, targets)


def pose_of(t: ProgramTarget) -> Array:
    """The point's pose in its user frame [m]: ``Trans(X, Y, Z) Rz(R) Ry(P) Rx(W)``."""
    return pose_mm_deg(*t.values(("x", "y", "z", "w", "p", "r")))


def pose_values(t: ProgramTarget, T: Array) -> dict[str, float]:
    """X, Y, Z [mm], W, P, R [deg] of T, angles near the point's own."""
    w0, p0, r0 = t.values(("w", "p", "r")).tolist()
    pole = 0.5 * 10.0 ** -t.slots["p"].style.decimals      # half the last written decimal
    x, y, z, w, p, r = xyz_rpy_mm_deg(T, (w0, p0, r0), pole)
    return {"x": x, "y": y, "z": z, "w": w, "p": p, "r": r}


def config_values(t: ProgramTarget, axes: Array, signs: Array) -> dict[str, float]:
    """Turn numbers of J1, J4, J6 (deg): turn t covers (-180 + 360 t, 180 + 360 t]."""
    if "turn1" not in t.slots:
        return {}
    return {key: float(np.ceil((axes[k] - 180.0) / 360.0))
            for key, k in (("turn1", 0), ("turn4", 3), ("turn6", 5))}
