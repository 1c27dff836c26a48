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

from kincal.compensation.configuration import fanuc_configuration
from kincal.compensation.programs.base import (
    Array,
    ProgramTarget,
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
_UF = re.compile(r"\bUF\s*:\s*(\d+)")
_UT = re.compile(r"\bUT\s*:\s*(\d+)")
_CONFIG = re.compile(r"\bCONFIG\s*:\s*'([^']*)'")
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


def read_ls(path: str) -> LsProgram:
    """Read a ``.ls`` program's points (group 1) and which of them ``/MN`` uses."""
    text = read_program_text(path)
    mn0, mn1 = _section(text, "MN")
    used = set()
    if mn0 >= 0:
        for mn_line in text[mn0:mn1].splitlines():
            code = (mn_line.split("!", 1)[0] if re.match(r"\s*\d*:\s*!", mn_line)
                    else mn_line)
            used |= {int(n) for n in _USE.findall(code)}
    p0, p1 = _section(text, "POS")
    targets: list[ProgramTarget] = []
    if p0 < 0:
        return LsProgram({path: text}, targets)
    for m in _POINT.finditer(text, p0, p1):
        end = text.find("};", m.end(), p1)
        if end < 0:
            raise fail(path, text, m.start(), f"point P[{m.group(1)}] is not closed with '}};'")
        body = (m.end(), end)
        groups = list(_GROUP.finditer(text, *body))
        g1 = next((g for g in groups if g.group(1) == "1"), None)
        if g1 is None:
            raise fail(path, text, m.start(), f"point P[{m.group(1)}] has no GP1 group")
        nxt = next((g.start() for g in groups if g.start() > g1.start()), end)
        seg = (g1.end(), nxt)
        name = f"P[{m.group(1)}" + (f':"{m.group(2)}"]' if m.group(2) is not None else "]")
        chunk = text[seg[0]:seg[1]]
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
            cf = _CONFIG.search(chunk)
            conf = None
            if cf is not None:
                parts = [p.strip() for p in cf.group(1).split(",")]
                try:
                    turns = [int(p) for p in parts[1:4]]
                except ValueError:
                    turns = []
                if len(parts) != 4 or len(turns) != 3:
                    raise fail(path, text, seg[0] + cf.start(1),
                               f"{name}: CONFIG must be 'F U T, t1, t4, t6', got {cf.group(1)!r}")
                conf = fanuc_configuration(parts[0], (turns[0], turns[1], turns[2]))
                base = seg[0] + cf.start(1)
                for key, nm in zip(("turn1", "turn4", "turn6"),
                                   list(re.finditer(r"[+-]?\d+", cf.group(1)))[-3:], strict=True):
                    slots[key] = number_slot(path, text, base + nm.start(), base + nm.end(),
                                             f"{name} CONFIG")
            first = min(s.start for s in slots.values())
            line, col = position(text, first)
            t = ProgramTarget(name, path, line, col, "pose", slots, conf, ut.group(1),
                              uf.group(1))
        elif joints:
            slots = {f"j{k}": number_slot(path, text, seg[0] + c.start(2), seg[0] + c.end(2),
                                          f"{name} J{k}") for k, c in joints.items()}
            if len(slots) < 6:
                raise fail(path, text, g1.start(), f"{name}: needs J1 ... J6")
            first = min(s.start for s in slots.values())
            line, col = position(text, first)
            t = ProgramTarget(name, path, line, col, "joints",
                              {k: slots[k] for k in JOINT_KEYS}, None, ut.group(1), uf.group(1))
        else:
            raise fail(path, text, g1.start(), f"{name}: GP1 has neither X ... R nor J1 ... J6")
        t.used = int(m.group(1)) in used
        targets.append(t)
    return LsProgram({path: text}, targets)


def pose_of(t: ProgramTarget) -> Array:
    """The point's pose in its user frame [m]: ``Trans(X, Y, Z) Rz(R) Ry(P) Rx(W)``."""
    return pose_mm_deg(*t.values(("x", "y", "z", "w", "p", "r")))


def pose_values(t: ProgramTarget, T: Array) -> dict[str, float]:
    """X, Y, Z [mm], W, P, R [deg] of T, angles near the point's own."""
    w0, p0, r0 = t.values(("w", "p", "r")).tolist()
    x, y, z, w, p, r = xyz_rpy_mm_deg(T, (w0, p0, r0))
    return {"x": x, "y": y, "z": z, "w": w, "p": p, "r": r}


def config_values(t: ProgramTarget, axes: Array, signs: Array) -> dict[str, float]:
    """Turn numbers of J1, J4, J6 (deg): turn t covers (-180 + 360 t, 180 + 360 t]."""
    if "turn1" not in t.slots:
        return {}
    return {key: float(np.ceil((axes[k] - 180.0) / 360.0))
            for key, k in (("turn1", 0), ("turn4", 3), ("turn6", 5))}
