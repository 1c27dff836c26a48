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
    fmt_value,
    joint_vector,
    matrix_table,
    robot_arg,
)
from kincal.io import write_json

QOpt = Annotated[str, typer.Option("--q", help="Joint values, comma separated: rad for revolute, "
                                   "m for prismatic joints (see --deg).")]
DegOpt = Annotated[bool, typer.Option("--deg", help="Revolute joint values are in degrees "
                                      "(prismatic stay in metres).")]


def _is_fivebar(robot: object) -> bool:
    return type(robot).__name__ == "FiveBar"


@app.command()
def robots() -> None:
    """List the built-in robots (`kincal show NAME` gives the parameters and their source)."""
    from kincal.robots.files import library_names
    from kincal.workflow.robots import load_any_robot

    t = Table(title="Built-in robots (use the name wherever ROBOT is asked)")
    for c in ("name", "joints", "convention", "description"):
        t.add_column(c, overflow="fold")
    for name in library_names():
        r = load_any_robot(name)
        if _is_fivebar(r):
            kinds, conv = "2 actuated", "fivebar"
        else:
            kinds = "".join("R" if j.kind == "revolute" else "P" for j in r.joints)
            conv = r.meta.get("convention", "")
        desc = str(getattr(r, "meta", {}).get("description", "")) or "five-bar parallel robot"
        short = desc if len(desc) <= 64 else desc[:63].rstrip(" ,") + "…"
        t.add_row(name, kinds, conv, escape(short))
    console.print(t)


def _print_robot(r: Any) -> None:
    """Joint table, parameter table (mm / deg for people) and the source of the numbers."""
    jt = Table(title=f"{r.name}: {r.n} joints ({r.meta.get('convention', '')})")
    for c in ("#", "joint", "type", "lower", "upper"):
        jt.add_column(c, justify="right" if c in ("#", "lower", "upper") else "left")
    for i, j in enumerate(r.joints, start=1):
        lims = (j.lower, j.upper)
        if j.kind == "revolute":
            lo, hi = (f"{math.degrees(v):.1f}°" if math.isfinite(v) else "-" for v in lims)
        else:
            lo, hi = (f"{v * 1e3:.1f} mm" if math.isfinite(v) else "-" for v in lims)
        jt.add_row(str(i), j.name, j.kind, lo, hi)
    console.print(jt)
    pt = Table(title=f"{r.name}: {r.num_params} parameters (SI inside; shown in mm and deg)")
    for c in ("parameter", "value", "unit", "role"):
        pt.add_column(c, justify="right" if c == "value" else "left")
    for name, v, u, role in zip(r.param_names, r.param_values, r.param_units, r.param_roles,
                                strict=True):
        pt.add_row(name, fmt_value(float(v), u), u, role)
    console.print(pt)
    if "source" in r.meta:
        console.print(f"[dim]source: {escape(str(r.meta['source']))}[/dim]")


@app.command()
def show(robot: RobotArg, base_link: BaseLink = None, tip_link: TipLink = None,
         json_out: JsonOut = None) -> None:
    """Show a robot's joints and its named parameters with units."""
    r = robot_arg(robot, base_link, tip_link)
    if _is_fivebar(r):
        from kincal.cli.fivebar import show_fivebar

        show_fivebar(r, console)
        return
    if json_out != "-":
        _print_robot(r)
    if json_out:
        write_json(json_out, {"name": r.name, "joints": [
            {"name": j.name, "type": j.kind, "lower": j.lower if math.isfinite(j.lower) else None,
             "upper": j.upper if math.isfinite(j.upper) else None} for j in r.joints],
            "parameters": [{"name": n, "value": float(v), "unit": u, "role": ro} for n, v, u, ro
                           in zip(r.param_names, r.param_values, r.param_units, r.param_roles,
                                  strict=True)]})


@app.command()
def fk(robot: RobotArg, q: QOpt, deg: DegOpt = False, base_link: BaseLink = None,
       tip_link: TipLink = None, json_out: JsonOut = None) -> None:
    """Forward kinematics: the tool pose T(q) in the base frame (metres)."""
    import numpy as np

    r = robot_arg(robot, base_link, tip_link)
    if _is_fivebar(r):
        from kincal.cli.fivebar import fk_fivebar

        fk_fivebar(r, joint_vector(r, q, deg), json_out)
        return
    T = r.fk(joint_vector(r, q, deg))
    if json_out != "-":
        console.print(matrix_table(T, f"{r.name}: T(q) \\[m]", digits=6))
        from kincal.spatial import matrix_to_rpy

        rpy = np.degrees(matrix_to_rpy(T[:3, :3]))
        console.print(f"position \\[mm]: {np.round(T[:3, 3] * 1e3, 4).tolist()}   "
                      f"rpy \\[deg]: {np.round(rpy, 4).tolist()}")
    if json_out:
        write_json(json_out, {"T": T.tolist(), "units": {"length": "m"}})


@app.command()
def jacobian(robot: RobotArg, q: QOpt, deg: DegOpt = False,
             frame: Annotated[str, typer.Option(help="base: velocities in the base frame; "
                                                "tool: in the tool frame.")] = "base",
             base_link: BaseLink = None, tip_link: TipLink = None,
             json_out: JsonOut = None) -> None:
    """Geometric Jacobian: rows vx vy vz [m/s per unit] and wx wy wz [rad/s per unit]."""
    import numpy as np

    r = robot_arg(robot, base_link, tip_link)
    J = r.jacobian(joint_vector(r, q, deg), frame=frame)  # type: ignore[arg-type]
    if json_out != "-":
        console.print(matrix_table(J, f"{r.name}: geometric Jacobian ({frame} frame)",
                                   ["vx", "vy", "vz", "wx", "wy", "wz"], list(r.joint_names)))
        s = np.linalg.svd(J, compute_uv=False)
        cond = s[0] / s[-1] if s[-1] > 0 else math.inf
        console.print(f"singular values: {np.round(s, 6).tolist()}   condition number: {cond:.4g}")
    if json_out:
        write_json(json_out, {"J": J.tolist(), "frame": frame,
                              "rows": ["vx", "vy", "vz", "wx", "wy", "wz"],
                              "columns": list(r.joint_names)})


