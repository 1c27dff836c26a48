"""The ``export`` command: write any robot as a YAML robot file or as a URDF.

The output format follows the file name: ``.yaml`` / ``.yml``
(:func:`kincal.robots.files.write_robot_yaml`: DH robots as DH tables unless
``--as-ets``, every other robot as an explicit elementary-transform chain; URDF-derived
robots get ``joint_units: si``) or ``.urdf`` (:func:`kincal.robots.urdf.write_urdf`: the
same forward kinematics from ``base_link`` to ``tool_link``).  Both are written
atomically, in SI units.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from kincal.cli.app import app
from kincal.cli.calibration_common import JsonOpt, load, out_console
from kincal.cli.common import BaseLink, RobotArg, TipLink, is_fivebar
from kincal.errors import KincalError
from kincal.io import check_outputs


@app.command("export")
def export_cmd(
    robot: RobotArg,
    output_opt: Annotated[str | None, typer.Option(
        "-o", "--output", metavar="OUT.(yaml|urdf)", help="File to write: .yaml / .yml "
        "(kincal robot file) or .urdf.")] = None,
    as_ets: Annotated[bool, typer.Option("--as-ets", help="YAML: write a DH robot as an "
                                         "explicit elementary-transform chain (convention: "
                                         "ets) instead of its DH table.")] = False,
    name: Annotated[str | None, typer.Option("--name", help="URDF: the <robot name=...> "
                                             "(default: the robot's name).")] = None,
    base_link: BaseLink = None, tip_link: TipLink = None, json_out: JsonOpt = None,
) -> None:
    """Write ROBOT (built-in name, YAML or URDF with --base-link/--tip-link) as a YAML robot
    file or a URDF with the same forward kinematics (SI units): kincal export ROBOT -o
    OUT.urdf."""
    output = output_opt
    if output is None:
        raise KincalError("`kincal export` needs -o OUT.yaml or -o OUT.urdf")
    console = out_console(json_out)
    check_outputs({"-o": output, "--json": json_out}, {"ROBOT": [robot]})
    suffix = Path(output).suffix.lower()
    if suffix not in (".yaml", ".yml", ".urdf"):
        raise KincalError(f"cannot tell the format of {output!r}: name it .yaml, .yml or "
                          ".urdf")
    r = load(robot, base_link, tip_link)
    if is_fivebar(r):
        if suffix == ".urdf" or as_ets:
            raise KincalError("the five-bar is a closed chain: it exports to YAML only "
                              "(without --as-ets)")
        from kincal.parallel.files import write_fivebar

        write_fivebar(r, output)
        console.print(f"five-bar {escape(r.name)} -> {escape(output)}")
        _json(json_out, r.name, output, "yaml")
        return
    if suffix == ".urdf":
        if as_ets:
            raise KincalError("--as-ets is for YAML output")
        from kincal.robots.urdf import write_urdf

        base, tip = write_urdf(r, output, name)
        from kincal.robots.files import write_envelope_sidecar

        side = write_envelope_sidecar(r, output)     # the calibration envelope travels
        if side is not None:
            console.print(f"calibration envelope -> {escape(str(side))} (keep it next to "
                          "the URDF)")
        console.print(f"{escape(r.name)} ({r.n} joints) -> {escape(output)} (URDF; chain "
                      f"{escape(base)} -> {escape(tip)}: use --base-link {escape(base)} "
                      f"--tip-link {escape(tip)} to load it)")
        _json(json_out, r.name, output, "urdf", base_link=base, tip_link=tip)
        return
    if name is not None:
        raise KincalError("--name is for URDF output")
    from kincal.robots.files import write_robot_yaml

    write_robot_yaml(r, output, as_ets=as_ets)
    conv = "ets" if as_ets else r.meta.get("convention", "ets")
    conv = conv if conv in ("standard_dh", "modified_dh", "hayati") else "ets"
    console.print(f"{escape(r.name)} ({r.n} joints) -> {escape(output)} (YAML, convention "
                  f"{conv}, SI units)")
    _json(json_out, r.name, output, "yaml", convention=conv)


def _json(path: str | None, robot: str, output: str, fmt: str, **more: str) -> None:
    if path:
        from kincal.io import write_json

        write_json(path, {"robot": robot, "output": output, "format": fmt, **more})
