"""The ``compensate`` command: joint commands (and filtered targets) from a calibrated robot.

Reads a target CSV (``x y z`` and optionally ``rx ry rz`` roll-pitch-yaw, with units;
optional joint columns seed the IK), solves the calibrated robot's IK for every target
(:func:`kincal.compensation.compensate.compensate`) and writes the joint commands, plus, with
``--nominal --filtered``, the targets to send to a controller that only knows the
nominal model.  Nothing is written unless every target is reached.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape

from kincal.cli.app import app
from kincal.cli.calibration_common import (
    IgnoreOpt,
    JsonOpt,
    UnitsOpt,
    check_unit,
    load,
    out_console,
    serial,
)
from kincal.cli.common import BaseLink, TipLink
from kincal.cli.options import SiOpt, use_si
from kincal.errors import CheckFailedError, KincalError, MeasurementFileError
from kincal.io import check_outputs

if TYPE_CHECKING:
    import numpy as np


def _target_fields() -> tuple[Any, ...]:
    from kincal.measure.files import Field

    return (Field(r"[xyz]", "length", "x, y, z"),
            Field(r"r[xyz]", "angle", "rx, ry, rz (roll-pitch-yaw)"))


def read_targets(path: str, robot: Any, units: str | None, ignore: Sequence[str] | None
                 ) -> tuple[np.ndarray, np.ndarray | None, Any]:
    """Targets (N, 4, 4) poses or (N, 3) positions [m], optional joint seeds (N, n)
    [rad / m], and the parsed table (for line numbers in messages).  Joint seeds beyond
    the robot's limits (or in the other angle unit) raise ``CheckFailedError`` (exit 1)
    naming the file and line."""
    import numpy as np

    from kincal.measure.files import (
        parse_list_option,
        parse_units_option,
        read_header,
        read_table,
        split_unit,
    )
    from kincal.spatial import homogeneous, rpy_to_matrix

    if not Path(path).is_file():
        raise MeasurementFileError("no such targets file", source=path)
    names = read_header(path)[1]
    has_joints = any(split_unit(n)[0] in robot.joint_names or n in robot.joint_names
                     for n in names)
    t = read_table(path, robot, _target_fields(), parse_units_option(units),
                   parse_list_option(ignore), joints=has_joints)
    for c in "xyz":
        if c not in t.values:
            raise t.error(f"missing target column {c!r} (with its unit, e.g. {c}_mm)")
    p = np.stack([t.values[c] for c in "xyz"], axis=1)
    rot = [c for c in ("rx", "ry", "rz") if c in t.values]
    if rot and len(rot) != 3:
        raise t.error("orientation targets need all of rx, ry, rz (roll-pitch-yaw)")
    targets = homogeneous(rpy_to_matrix(np.stack([t.values[c] for c in ("rx", "ry", "rz")],
                                                 axis=1)), p) if rot else p
    if has_joints:                      # joint seeds the robot cannot take: refused
        from kincal.measure.data_checks import joint_data_line, joint_data_problems

        bad = joint_data_line(joint_data_problems(
            robot, t.q, path, list(t.lines), [t.units.get(j) for j in robot.joint_names]))
        if bad:
            raise CheckFailedError(f"joint seeds this robot cannot take: {bad}")
    return targets, (t.q if has_joints else None), t


@app.command("compensate")
def compensate_cmd(
    calibrated: Annotated[str, typer.Argument(
        metavar="CALIBRATED", help="The calibrated robot file (from `kincal calibrate -o`).")],
    targets: Annotated[str, typer.Option("--targets", "-t", help="Target CSV: x, y, z (and rx, "
                                         "ry, rz roll-pitch-yaw) with units; optional joint "
                                         "columns seed the IK.")],
    output: Annotated[str, typer.Option("-o", "--output", help="Joint commands CSV to write.")],
    nominal: Annotated[str | None, typer.Option("--nominal", help="The controller's nominal "
                                                "robot: needed for --filtered, and seeds the IK "
                                                "on the controller's branch.")] = None,
    filtered: Annotated[str | None, typer.Option("--filtered", help="Write filtered targets "
                                                 "here: FK_nominal(q_cmd), to send to a "
                                                 "controller that only knows the nominal "
                                                 "model.")] = None,
    result: Annotated[str | None, typer.Option(
        "--result", help="Result JSON of `kincal calibrate`: the predicted accuracy at every "
        "target (the calibration's covariance and unmodelled floor), the targets outside "
        "the calibrated region, and where the calibrated model is predicted worse than the "
        "nominal one. Default: the envelope a calibrated robot file carries.")] = None,
    fallback: Annotated[str, typer.Option(
        "--fallback", metavar="none|nominal", help="nominal: where the calibrated model is "
        "predicted worse than the nominal one (needs --nominal and a prediction), send the "
        "target uncompensated (the nominal IK's joints; the target itself as filtered "
        "target). none (default): compensate every target, warn.")] = "none",
    units: UnitsOpt = None, ignore: IgnoreOpt = None,
    length_unit: Annotated[str | None, typer.Option(
        "--length-unit", help="Length unit of the written files: m, mm, um (default: the "
        "targets file's).")] = None,
    angle_unit: Annotated[str | None, typer.Option(
        "--angle-unit", help="Angle unit of the written files: rad, deg (default: the "
        "targets file's).")] = None,
    base_link: BaseLink = None, tip_link: TipLink = None, si: SiOpt = False,
    json_out: JsonOpt = None,
) -> None:
    """Joint commands that put the calibrated (real) robot on the targets, and filtered
    targets for a controller that only knows the nominal model; written in the units of
    the targets file (mm/deg targets give joint commands in deg) unless told."""
    import numpy as np

    from kincal.io import atomic_write_text, write_json
    from kincal.measure.files import format_table, joint_columns
    from kincal.spatial import matrix_to_rpy
    from kincal.units import UNITS
    from kincal.workflow.compensation import compensate_targets

    out = out_console(json_out)
    cu = use_si(si)
    check_outputs({"-o": output, "--filtered": filtered, "--json": json_out},
                  {"--targets": [targets], "CALIBRATED": [calibrated],
                   "--nominal": [nominal] if nominal else []})
    cal = serial(load(calibrated, base_link, tip_link), "compensate")
    nom = serial(load(nominal, base_link, tip_link), "compensate") if nominal else None
    if filtered and nom is None:
        raise KincalError("--filtered needs --nominal (the controller's model)")
    if length_unit is not None:
        check_unit(length_unit, "length", "--length-unit")
    if angle_unit is not None:
        check_unit(angle_unit, "angle", "--angle-unit")
    if fallback not in ("none", "nominal"):
        raise KincalError(f"option --fallback: {fallback!r} is not none or nominal")
    if result:
        from kincal.workflow.flow import accuracy_from_result

        accuracy = accuracy_from_result(result, cal)
    else:                               # the envelope the calibrated robot carries
        from kincal.identify.envelope import robot_and_accuracy

        cal, accuracy = robot_and_accuracy(cal)
    if fallback == "nominal" and (nom is None or accuracy is None):
        raise KincalError("--fallback nominal needs --nominal (the controller's model) and "
                          "the predicted accuracy (--result, or a calibrated robot file)")
    T, seeds, table = read_targets(targets, cal, units, ignore)
    length_unit = length_unit or table.units.get("x", "m")
    angle_unit = angle_unit or table.units.get("rx", "rad" if length_unit == "m" else "deg")
    run = compensate_targets(cal, T, nominal=nom, seeds=seeds, accuracy=accuracy,
                             fallback="nominal" if fallback == "nominal" else "none",
                             source=targets, lines=table.lines, output=output)
    comp, pred = run.compensation, run.predicted
    cols = [(name, comp.q[:, k] * f) for k, (name, f) in
            enumerate(joint_columns(cal, cal.n, angle_unit, length_unit))]
    jtext = format_table(cols, comments=[f"joint commands for {cal.name} from {targets}: "
                                         "the calibrated robot reaches each target"])
    ftext = None
    if filtered and comp.filtered is not None:
        lf, af = 1.0 / UNITS[length_unit][1], 1.0 / UNITS[angle_unit][1]
        F = comp.filtered
        fcols = [(f"{c}_{length_unit}", F[:, i, 3] * lf) for i, c in enumerate("xyz")]
        if comp.mask == "pose":
            rpy = matrix_to_rpy(F[:, :3, :3])
            fcols += [(f"{c}_{angle_unit}", rpy[:, i] * af)
                      for i, c in enumerate(("rx", "ry", "rz"))]
        ftext = format_table(fcols, comments=["filtered targets: send these to the nominal "
                                              "controller (its IK gives the joint commands)"])
    atomic_write_text(output, jtext)
    if ftext is not None and filtered:
        atomic_write_text(filtered, ftext)
    L, A = cu.length_unit, cu.angle_unit
    out.print(f"{len(comp)} targets ({comp.mask}): calibrated FK of the commands matches the "
              f"targets to {np.max(comp.position_error) * cu.scale('m')[0]:.2e} {L}"
              + (f" / {np.max(comp.orientation_error) * cu.scale('rad')[0]:.2e} {A}"
                 if comp.mask == "pose" else ""))
    if comp.branch_changes.size:
        lines = ", ".join(str(int(table.lines[i])) for i in comp.branch_changes[:10])
        out.print(f"[yellow]warning[/yellow]: {comp.branch_changes.size} target(s) (lines "
                  f"{lines}) needed a different joint configuration than the nominal IK "
                  "(near a singularity or a limit); check them before sending.")
    if comp.correction is not None:
        out.print(f"compensation size |filtered - target|: RMS "
                  f"{cu.value(math.sqrt(np.mean(comp.correction**2)), 'm')}, max "
                  f"{cu.value(float(np.max(comp.correction)), 'm')}")
    if pred is not None:
        _print_prediction(out, pred, comp, table, cu)
    out.print(f"joint commands ({angle_unit} / {length_unit}) -> {escape(output)}"
              + (f"; filtered targets -> {escape(filtered)}" if ftext and filtered else ""))
    if json_out:
        write_json(json_out, run.to_dict())


def _print_prediction(out: Any, pred: Any, comp: Any, table: Any, cu: Any) -> None:
    """The predicted accuracy at the targets: the region summary, the targets where the
    calibrated model is predicted worse than the nominal one, the fallback."""
    import numpy as np

    from kincal.identify.envelope import outside_line

    for sentence in pred.summary("targets", unit=cu.scale("m")):
        out.print(f"predicted: {escape(sentence)}")
    loud = outside_line(pred, "targets", "the calibrated robot", cu.scale("m"))
    if loud:
        out.print(f"[bold yellow]warning[/bold yellow]: {escape(loud)}")
    worse = np.flatnonzero(pred.worse_than_nominal)
    if worse.size:
        lines = ", ".join(str(int(table.lines[i])) for i in worse[:10])
        more = f" and {worse.size - 10} more" if worse.size > 10 else ""
        if comp.fallback is not None and comp.fallback.any():
            out.print(f"[yellow]fallback[/yellow]: {worse.size} target(s) (lines {lines}{more}) "
                      "sent uncompensated (nominal IK, target as filtered target): the "
                      "calibrated model is predicted worse than the nominal one there")
        else:
            i = int(worse[0])
            out.print(f"[yellow]warning[/yellow]: {worse.size} target(s) (lines "
                      f"{lines}{more}): the calibrated model is predicted worse than the "
                      f"nominal one there (e.g. line {int(table.lines[i])}: correction "
                      f"{cu.value(float(pred.correction_m[i]), 'm')} within its uncertainty "
                      f"{cu.value(float(pred.std_position_m[i]), 'm')}); --fallback nominal "
                      "sends them uncompensated")
