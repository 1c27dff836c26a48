"""``kincal import ...``: other tools' files in, kincal's out.

* ``kincal import ur FILE --nominal UR -o robot.yaml [--kinematics kin.yaml]``: a UR
  controller's ``calibration.conf`` or a ROS kinematics YAML as a kincal robot file
  (:mod:`kincal.robots.ur`);
* ``kincal ur-kinematics ROBOT --nominal UR -o kinematics.yaml``: any calibrated UR as the
  ROS kinematics YAML (for ur_description / the UR ROS drivers);
* ``kincal import bag BAG -o data.csv ...``: static postures from a ROS bag
  (:mod:`kincal.measure.bags`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from kincal.cli.app import app
from kincal.cli.calibration_common import load, out_console, serial
from kincal.errors import KincalError

import_app = typer.Typer(help="Other tools' files in: UR calibration files, ROS bags.",
                         no_args_is_help=True, rich_markup_mode=None)
app.add_typer(import_app, name="import")

NominalOpt = Annotated[str, typer.Option("--nominal", help="The built-in UR the file corrects "
                                         "(ur3, ur5, ur10, ur3e, ur5e, ur10e, ur16e) or a "
                                         "robot file.")]


def _round_trip_report(out, robot, nominal, text: str) -> float:
    import numpy as np

    from kincal.robots.ur import check_round_trip

    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (200, robot.n))
    err = check_round_trip(robot, text, nominal, q)
    out.print(f"kinematics YAML: forward kinematics round trip {err * 1e3:.2e} mm over 200 "
              "random postures")
    if err > 1e-9:
        raise KincalError(f"the kinematics YAML does not reproduce {robot.name!r} "
                          f"({err * 1e3:.3g} mm)")
    return err


@import_app.command("ur")
def import_ur(
    file: Annotated[str, typer.Argument(help="calibration.conf from the UR controller, or a "
                                        "ROS kinematics YAML (kinematics: {shoulder: ...}).")],
    nominal: NominalOpt,
    output: Annotated[str, typer.Option("-o", "--output", help="kincal robot file to write.")],
    kinematics: Annotated[str | None, typer.Option("--kinematics", help="Also write the robot "
                                                   "as a ROS kinematics YAML here.")] = None,
) -> None:
    """Read a UR controller's calibration (calibration.conf) or a ROS kinematics YAML as a
    kincal robot file."""
    import numpy as np

    from kincal.io import atomic_write_text
    from kincal.robots.files import robot_yaml_text
    from kincal.robots.ur import kinematics_yaml, read_calibration_conf, read_kinematics_yaml

    out = out_console(None)
    nom = serial(load(nominal), "import ur")
    if not Path(file).is_file():
        raise KincalError("no such file", source=file)
    is_yaml = Path(file).suffix.lower() in (".yaml", ".yml")
    robot = read_kinematics_yaml(file, nom) if is_yaml else read_calibration_conf(file, nom)
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (500, robot.n))
    diff = np.linalg.norm(robot.fk(q)[:, :3, 3] - nom.fk(q)[:, :3, 3], axis=1)
    kin_text = kinematics_yaml(robot, nom) if kinematics else None
    if kin_text is not None:
        _round_trip_report(out, robot, nom, kin_text)
    atomic_write_text(output, robot_yaml_text(robot))
    if kin_text is not None and kinematics:
        atomic_write_text(kinematics, kin_text)
    out.print(f"{escape(Path(file).name)}: {robot.name} differs from nominal {nom.name} by "
              f"{np.sqrt(np.mean(diff ** 2)) * 1e3:.4f} mm RMS, {diff.max() * 1e3:.4f} mm max at "
              "the flange (500 random postures)")
    out.print(f"robot -> {escape(output)}" + (f"; kinematics YAML -> {escape(kinematics)}"
                                               if kinematics else ""))


@app.command("ur-kinematics")
def ur_kinematics(
    robot: Annotated[str, typer.Argument(help="A calibrated UR (robot file from `kincal "
                                         "calibrate -o` or `kincal import ur`).")],
    nominal: NominalOpt,
    output: Annotated[str, typer.Option("-o", "--output", help="ROS kinematics YAML to "
                                        "write.")],
) -> None:
    """Write a calibrated UR as the ROS kinematics YAML (ur_description's
    default_kinematics.yaml format), every joint origin near its nominal value."""
    from kincal.io import atomic_write_text
    from kincal.robots.ur import kinematics_yaml

    out = out_console(None)
    r = serial(load(robot), "ur-kinematics")
    nom = serial(load(nominal), "ur-kinematics")
    text = kinematics_yaml(r, nom)
    _round_trip_report(out, r, nom, text)
    atomic_write_text(output, text)
    out.print(f"kinematics YAML -> {escape(output)}")
