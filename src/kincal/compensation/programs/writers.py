"""Joint-move programs for the measurement poses of a calibration plan.

``kincal plan ... --program DIALECT`` writes the chosen poses as a program that moves
the robot through them with joint moves, stopping at each one (``--dwell``) so that the
instrument can measure.  Axis values are the controller's (:class:`ControllerMap`):
degrees for KUKA, ABB and FANUC, radians for UR; 4 decimals (6 for UR).  The readers
of this package read the written programs back (the tests check it).
"""

from __future__ import annotations

from datetime import date

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.robots.chain import Robot
from kincal.robots.controller import controller_map

Array = NDArray[np.float64]
PROGRAM_DIALECTS = ("krl", "rapid", "urscript", "fanuc-ls")
SUFFIX = {"krl": ".src", "rapid": ".mod", "urscript": ".script", "fanuc-ls": ".ls"}
_VENDOR = {"krl": "kuka", "rapid": "abb", "urscript": "ur", "fanuc-ls": "fanuc"}


def _name(name: str, limit: int) -> str:
    clean = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in name)
    if not clean or not clean[0].isalpha():
        clean = "p" + clean
    return clean[:limit]


def joint_program(dialect: str, robot: Robot, q: Array, name: str = "calib_poses",
                  dwell: float = 2.0, speed_percent: int = 10) -> str:
    """The text of a program visiting joint configurations q (N, n) [rad] in order.

    Args:
        dialect: one of :data:`PROGRAM_DIALECTS`.
        robot: the robot (its controller map converts q to axis values).
        name: program / module name.
        dwell: standstill at each pose [s], for the measurement.
        speed_percent: joint speed, percent of the maximum (KRL, FANUC; ABB and UR get
            an equivalent slow speed).
    """
    if dialect not in PROGRAM_DIALECTS:
        raise KincalError(f"option --program: unknown dialect {dialect!r}; use "
                          f"{', '.join(PROGRAM_DIALECTS)}")
    cmap = controller_map(robot, _VENDOR[dialect])
    if cmap.vendor and cmap.vendor != _VENDOR[dialect]:
        raise KincalError(f"robot {robot.name!r} has a {cmap.vendor} controller; a "
                          f"{dialect} program cannot drive it")
    axes = cmap.to_axes(np.atleast_2d(q))
    if axes.shape[1] != 6 and dialect in ("krl", "fanuc-ls"):
        raise KincalError(f"{dialect} programs here are for 6-axis robots; {robot.name!r} has "
                          f"{axes.shape[1]} joints")
    head = (f"calibration poses for {robot.name}: {len(axes)} joint moves, {dwell:g} s "
            f"standstill at each for the measurement (kincal, {date.today().isoformat()})")
    if dialect == "krl":
        nm = _name(name, 24)
        lines = ["&ACCESS RVP", f"DEF {nm}( )", f"; {head}", "BAS(#INITMOV,0)",
                 f"BAS(#VEL_PTP,{speed_percent})"]
        for i, a in enumerate(axes, 1):
            lines.append(f"; pose {i}")
            lines.append("PTP {" + ", ".join(f"A{k + 1} {v:.4f}" for k, v in enumerate(a))
                         + "}")
            lines.append(f"WAIT SEC {dwell:.1f}")
        lines.append("END")
        return "\r\n".join(lines) + "\r\n"
    if dialect == "rapid":
        nm = _name(name, 30)
        lines = [f"MODULE {nm}", f"  ! {head}"]
        for i, a in enumerate(axes, 1):
            lines.append(f"  CONST jointtarget jPose{i}:=[[" + ",".join(f"{v:.4f}" for v in a)
                         + "],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];")
        lines += ["", "  PROC main()"]
        for i in range(1, len(axes) + 1):
            lines.append(f"    MoveAbsJ jPose{i}\\NoEOffs, v100, fine, tool0;")
            lines.append(f"    WaitTime {dwell:.1f};")
        lines += ["  ENDPROC", "ENDMODULE"]
        return "\r\n".join(lines) + "\r\n"
    if dialect == "urscript":
        nm = _name(name, 40)
        lines = [f"def {nm}():", f"  # {head}"]
        for i, a in enumerate(axes, 1):
            lines.append(f"  movej([{', '.join(f'{v:.6f}' for v in a)}], a=0.5, v=0.3)"
                         f"   # pose {i}")
            lines.append(f"  sleep({dwell:.1f})")
        lines += ["end", f"{nm}()"]
        return "\n".join(lines) + "\n"
    nm = _name(name, 8).upper()
    mn = [f"   1:  ! {head[:60]} ;"]
    k = 2
    for i in range(1, len(axes) + 1):
        mn.append(f"{k:4d}:J P[{i}] {speed_percent}% FINE    ;")
        mn.append(f"{k + 1:4d}:  WAIT {dwell:6.2f}(sec) ;")
        k += 2
    pos = []
    for i, a in enumerate(axes, 1):
        vals = [f"J{j + 1}={v:10.3f} deg" for j, v in enumerate(a)]
        pos += [f"P[{i}]{{", "   GP1:", "\tUF : 0, UT : 0,\t",
                "\t" + ",\t".join(vals[:3]) + ",", "\t" + ",\t".join(vals[3:]), "};"]
    lines = [f"/PROG  {nm}", "/ATTR", "OWNER\t\t= MNEDITOR;", 'COMMENT\t\t= "kincal poses";',
             f"LINE_COUNT\t= {len(mn)};", "PROTECT\t\t= READ_WRITE;",
             "DEFAULT_GROUP\t= 1,*,*,*,*;", "/MN", *mn, "/POS", *pos, "/END"]
    return "\r\n".join(lines) + "\r\n"
