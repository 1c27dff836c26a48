"""Kinematics commands: ``robots``, ``show``, ``fk``, ``jacobian``."""

from __future__ import annotations

import math
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from kincal.cli.app import app
from kincal.cli.common import (
    BaseLink,
    JsonOut,
    RobotArg,
    TipLink,
    console,
    err_console,
    is_fivebar,
    joint_vector,
    matrix_table,
    robot_arg,
)
from kincal.cli.options import DegOpt, SiOpt, Units
from kincal.io import write_json

QOpt = Annotated[str, typer.Option("--q", help="Joint values, comma separated: rad for revolute, "
                                   "m for prismatic joints (see --deg).")]


SearchOpt = Annotated[str | None, typer.Option(
    "--search", help="Show only robots whose name, vendor or description contains this text "
    "(case-insensitive), e.g. 'kr 16', 'collaborative', 'irb'.", show_default=False)]
VendorOpt = Annotated[str | None, typer.Option(
    "--vendor", help="Show only this vendor's robots (case-insensitive, part of the name is "
    "enough: kuka, abb, fanuc, universal, franka, yaskawa).", show_default=False)]


def _short_source(text: str, width: int = 130) -> str:
    """The first clause of a robot file's ``source`` (who published the numbers, where)."""
    head = text.split(": ", 1)[0].strip()
    return head if len(head) <= width else head[:width - 1].rstrip(" ,") + "…"


@app.command()
def robots(search: SearchOpt = None, vendor: VendorOpt = None, json_out: JsonOut = None) -> None:
    """List the built-in robots with their vendor and the source of their numbers
    (`kincal show NAME` gives the parameters and the full source)."""
    from kincal.errors import KincalError
    from kincal.robots.files import library_names
    from kincal.workflow.robots import load_any_robot

    t = Table(title="Built-in robots (use the name wherever ROBOT is asked)")
    for c in ("name", "vendor", "joints", "convention", "description", "source"):
        t.add_column(c, overflow="fold")
    rows = []
    vendors: set[str] = set()
    for name in library_names():
        r = load_any_robot(name)
        meta = getattr(r, "meta", {})
        if is_fivebar(r):
            kinds, conv = "2 actuated", "fivebar"
        else:
            kinds = "".join("R" if j.kind == "revolute" else "P" for j in r.joints)
            conv = meta.get("convention", "")
        desc = str(meta.get("description", "")) or "five-bar parallel robot"
        who = str(meta.get("vendor", ""))
        source = str(meta.get("source", ""))
        vendors.add(who) if who else None
        if vendor is not None and vendor.strip().lower() not in who.lower():
            continue
        if search is not None and search.strip().lower() not in \
                " ".join((name, who, desc)).lower():
            continue
        short = desc if len(desc) <= 64 else desc[:63].rstrip(" ,") + "…"
        t.add_row(name, escape(who), kinds, conv, escape(short), escape(_short_source(source)))
        rows.append({"name": name, "vendor": who, "joints": kinds, "convention": conv,
                     "description": desc, "source": source})
    if not rows and (vendor is not None or search is not None):
        what = " and ".join(x for x in (f"vendor {vendor!r}" if vendor is not None else "",
                                         f"--search {search!r}" if search is not None else "")
                         if x)
        raise KincalError(f"no built-in robot matches {what} (vendors: "
                          f"{', '.join(sorted(vendors))})")
    if json_out != "-":
        console.print(t)
    if json_out:
        write_json(json_out, {"robots": rows})


def _print_robot(r: Any, units: Units) -> None:
    """Joint table, parameter table (mm / deg, or SI with --si), the source and the notes."""
    out = console
    jt = Table(title=f"{r.name}: {r.n} joints ({r.meta.get('convention', '')})")
    for c in ("#", "joint", "type", "lower", "upper"):
        jt.add_column(c, justify="right" if c in ("#", "lower", "upper") else "left")
    for i, j in enumerate(r.joints, start=1):
        lims = (j.lower, j.upper)
        unit = "rad" if j.kind == "revolute" else "m"
        lo, hi = (units.value(v, unit, 1 if not units.si else 4) if math.isfinite(v) else "-"
                  for v in lims)
        jt.add_row(str(i), j.name, j.kind, lo, hi)
    out.print(jt)
    held = dict(r.meta.get("held_joints") or {})
    if held:
        out.print("held joints: " + ", ".join(f"{escape(k)} = {v:g}" for k, v in held.items()))
    pt = Table(title=f"{r.name}: {r.num_params} parameters")
    for c in ("parameter", "value", "unit", "role"):
        pt.add_column(c, justify="right" if c == "value" else "left")
    for name, v, u, role in zip(r.param_names, r.param_values, r.param_units, r.param_roles,
                                strict=True):
        f, cu = units.scale(u)
        pt.add_row(name, f"{float(v) * f:.{4 if not units.si else 7}f}", cu, role)
    out.print(pt)
    for key in ("source", "notes"):
        if r.meta.get(key):
            out.print(f"[bold]{key}[/bold]: {escape(' '.join(str(r.meta[key]).split()))}")


@app.command()
def show(robot: RobotArg, base_link: BaseLink = None, tip_link: TipLink = None,
         si: SiOpt = False, json_out: JsonOut = None) -> None:
    """Show a robot's joints and its named parameters with units (mm and degrees; --si: m
    and rad), where its numbers come from, and its notes."""
    r = robot_arg(robot, base_link, tip_link)
    if is_fivebar(r):
        from kincal.cli.fivebar import show_fivebar

        show_fivebar(r, console if json_out != "-" else err_console, Units(si), json_out)
        return
    if json_out != "-":
        _print_robot(r, Units(si))
    if json_out:
        write_json(json_out, {"name": r.name, "joints": [
            {"name": j.name, "type": j.kind, "lower": j.lower if math.isfinite(j.lower) else None,
             "upper": j.upper if math.isfinite(j.upper) else None} for j in r.joints],
            "parameters": [{"name": n, "value": float(v), "unit": u, "role": ro} for n, v, u, ro
                           in zip(r.param_names, r.param_values, r.param_units, r.param_roles,
                                  strict=True)],
            "units": {"length": "m", "angle": "rad"},
            **{k: str(r.meta[k]) for k in ("description", "source", "notes") if k in r.meta}})


@app.command()
def fk(robot: RobotArg, q: QOpt, deg: DegOpt = False, si: SiOpt = False,
       base_link: BaseLink = None, tip_link: TipLink = None, json_out: JsonOut = None) -> None:
    """Forward kinematics: the tool pose T(q) in the base frame (position in mm and
    roll-pitch-yaw in degrees; --si: m and rad)."""
    import numpy as np

    r = robot_arg(robot, base_link, tip_link)
    if is_fivebar(r):
        from kincal.cli.fivebar import fk_fivebar

        fk_fivebar(r, joint_vector(r, q, deg), json_out)
        return
    qv = joint_vector(r, q, deg)
    T = r.fk(qv)
    from kincal.cli.envelope_lines import envelope_report
    from kincal.spatial import matrix_to_rpy

    rpy = matrix_to_rpy(T[:3, :3])
    if json_out != "-":
        u = Units(si)
        M = T.copy()
        M[:3, 3] *= u.scale("m")[0]
        console.print(matrix_table(M, f"{r.name}: T(q) (translation \\[{u.length_unit}])",
                                   digits=6))
        console.print(f"position \\[{u.length_unit}]: "
                      f"{', '.join(u.length(v) for v in T[:3, 3])}   "
                      f"rpy \\[{u.angle_unit}]: {', '.join(u.angle(v) for v in rpy)}")
    trust = envelope_report(err_console if json_out == "-" else console, r, qv,
                            "configurations", Units(si).scale("m"), quiet=json_out == "-")
    if json_out:
        write_json(json_out, {"T": T.tolist(), "position": T[:3, 3].tolist(),
                              "rpy": np.asarray(rpy).tolist(),
                              "units": {"length": "m", "angle": "rad"},
                              **({"calibration_envelope": trust} if trust else {})})
    _refuse_beyond_limits(r, qv, deg)


def _refuse_beyond_limits(robot: Any, q: Any, deg: bool) -> None:
    """Exit 1 with one line when ``--q`` lies beyond the joint limits (the answer was
    printed: it is the kinematics of a configuration the robot cannot take)."""
    from kincal.errors import CheckFailedError
    from kincal.measure.data_checks import command_line_joints

    line = command_line_joints(robot, q, "--q", deg)
    if line:
        raise CheckFailedError(line)


@app.command()
def jacobian(robot: RobotArg, q: QOpt, deg: DegOpt = False,
             frame: Annotated[str, typer.Option(help="base: velocities in the base frame; "
                                                "tool: in the tool frame.")] = "base",
             si: SiOpt = False, base_link: BaseLink = None, tip_link: TipLink = None,
             json_out: JsonOut = None) -> None:
    """Geometric Jacobian: rows vx vy vz (mm/s) and wx wy wz (deg/s) per unit joint speed
    (rad/s, deg/s with --deg; m/s for prismatic joints); --si: m/s and rad/s."""
    import numpy as np

    r = robot_arg(robot, base_link, tip_link)
    qv = joint_vector(r, q, deg)
    J = r.jacobian(qv, frame=frame)
    if json_out != "-":
        u = Units(si)
        M = J.copy()
        M[:3] *= u.scale("m")[0]
        M[3:] *= u.scale("rad")[0]
        rev = np.array([j.kind == "revolute" for j in r.joints])
        if deg:
            M[:, rev] *= math.pi / 180.0
        per = [("deg/s" if deg else "rad/s") if k else "m/s" for k in rev]
        console.print(matrix_table(M, f"{r.name}: geometric Jacobian ({frame} frame; rows "
                                   f"{u.length_unit}/s and {u.angle_unit}/s per joint speed)",
                                   ["vx", "vy", "vz", "wx", "wy", "wz"],
                                   [escape(f"{n} [{p}]") for n, p in zip(r.joint_names, per,
                                                                         strict=True)]))
        s = np.linalg.svd(J, compute_uv=False)
        cond = s[0] / s[-1] if s[-1] > 0 else math.inf
        console.print(f"singular values (SI): {np.round(s, 6).tolist()}   condition number: "
                      f"{cond:.4g}")
    if json_out:
        write_json(json_out, {"J": J.tolist(), "frame": frame,
                              "rows": ["vx", "vy", "vz", "wx", "wy", "wz"],
                              "columns": list(r.joint_names),
                              "units": "SI: m/s and rad/s per rad/s (revolute) or m/s "
                                       "(prismatic)"})
    _refuse_beyond_limits(r, qv, deg)
