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

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape

from kincal.cli.app import app
from kincal.cli.calibration_common import JsonOpt, load, out_console, serial
from kincal.errors import KincalError

if TYPE_CHECKING:                 # types only: the robots load lazily (start-up time)
    from rich.console import Console

    from kincal.robots.chain import Robot

import_app = typer.Typer(help="Other tools' files in: UR calibration files, ROS bags.",
                         no_args_is_help=True, rich_markup_mode=None)
app.add_typer(import_app, name="import")

NominalOpt = Annotated[str, typer.Option("--nominal", help="The built-in UR the file corrects "
                                         "(ur3, ur5, ur10, ur3e, ur5e, ur10e, ur16e, ur20, "
                                         "ur30) or a robot file.")]
#: What the UR driver logs when the kinematics YAML's hash is not the robot's checksum.
DRIVER_NOTE = ("hash {hash}: the UR driver compares it with the robot's calibration checksum "
               "and logs an ERROR 'The calibration parameters of the connected robot don't "
               "match the ones from the given kinematics config file' at every start: expected "
               "for a calibration other than the factory's (docs/tutorials/ur-calibration.md)")


def _yaml_params(robot: Robot, nom: Robot) -> dict[str, float]:
    """The kinematics-YAML numbers of ``robot`` (frames nearest ``nom``'s): x, y, z [m],
    roll, pitch, yaw [rad] per joint, named ``<link>.<key>``."""
    import yaml

    from kincal.robots.ur import kinematics_yaml

    kin = yaml.safe_load(kinematics_yaml(robot, nom))["kinematics"]
    return {f"{link}.{k}": float(v) for link, e in kin.items() if isinstance(e, dict)
            for k, v in e.items()}


def _worst(robot: Robot, nom: Robot) -> tuple[str, float, float, str]:
    """The parameter farthest from nominal in tolerances: (name, change, tolerance, unit).

    Both robots are written as kinematics YAMLs with frames nearest the nominal's, so a
    factory fit that slid frames along parallel axes compares by what it changed.  The
    tolerances are ``calibrate``'s defaults (1 mm, 0.1 deg; kincal.identify.tolerances)."""
    import math

    from kincal.identify.tolerances import DEFAULT_TOLERANCES

    a, b = _yaml_params(robot, nom), _yaml_params(nom, nom)
    best = ("", 0.0, 1.0, "m")
    for k, v in a.items():
        length = k.endswith((".x", ".y", ".z"))
        tol = DEFAULT_TOLERANCES["length"]["m"] if length else DEFAULT_TOLERANCES["angle"]["rad"]
        d = v - b[k] if length else math.remainder(v - b[k], 2 * math.pi)
        if abs(d) / tol > abs(best[1]) / best[2]:
            best = (k, d, tol, "m" if length else "rad")
    return best


def _check_plausible(file: str, robot: Robot, nom: Robot,
                     reread: Callable[[Robot], Robot]) -> None:
    """Refuse (exit 1) a file whose numbers are more than PLAUSIBLE tolerances from the
    nominal: another model, or a frame turned.  ``reread(nominal)`` reads the file again on
    another nominal, to name the built-in UR that fits best."""
    import math

    from kincal.errors import CheckFailedError
    from kincal.identify.tolerances import PLAUSIBLE
    from kincal.robots.files import load_serial_robot
    from kincal.robots.ur import UR_MODELS

    name, d, tol, unit = _worst(robot, nom)
    if abs(d) <= PLAUSIBLE * tol:
        return
    fits: list[tuple[float, str]] = []
    for m in UR_MODELS:
        if m == nom.name:
            continue
        try:
            other = load_serial_robot(m)
            _, d2, tol2, _ = _worst(reread(other), other)
        except KincalError:
            continue
        fits.append((abs(d2) / tol2, m))
    shown = f"{d * 1e3:+.3f} mm" if unit == "m" else f"{math.degrees(d):+.3f} deg"
    tol_s = f"{tol * 1e3:g} mm" if unit == "m" else f"{math.degrees(tol):g} deg"
    ratio, model = min(fits) if fits else (math.inf, "")
    cause = (f"the file is of a {model} (its numbers are within {ratio:.2g} tolerances of "
             f"it): use --nominal {model}" if ratio <= PLAUSIBLE else
             "no built-in UR fits it: a frame turned (e.g. by pi), another base convention or "
             "another model; check the file")
    raise CheckFailedError(f"{name} is {shown} from nominal {nom.name} ({abs(d) / tol:.3g}x its "
                           f"tolerance {tol_s}, more than {PLAUSIBLE:g}x): {cause}; --force "
                           "imports it anyway", source=file)


def _round_trip_report(out: Console, robot: Robot, nominal: Robot, text: str) -> float:
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
    force: Annotated[bool, typer.Option("--force", help="Import even when a number is more "
                                        "than 10 tolerances from the nominal (another model? a "
                                        "frame turned?).")] = False,
    json_out: JsonOpt = None,
) -> None:
    """Read a UR controller's calibration (calibration.conf) or a ROS kinematics YAML as a
    kincal robot file."""
    import numpy as np

    from kincal.io import atomic_write_text, check_outputs
    from kincal.robots.files import robot_yaml_text
    from kincal.robots.ur import kinematics_yaml, read_calibration_conf, read_kinematics_yaml

    out = out_console(json_out)
    check_outputs({"-o": output, "--kinematics": kinematics, "--json": json_out},
                  {"FILE": [file], "--nominal": [nominal]})
    nom = serial(load(nominal), "import ur")
    if not Path(file).is_file():
        raise KincalError("no such file", source=file)
    is_yaml = Path(file).suffix.lower() in (".yaml", ".yml")
    def reread(n: Robot) -> Robot:
        return read_kinematics_yaml(file, n) if is_yaml else read_calibration_conf(file, n)

    robot = reread(nom)
    if not force:
        _check_plausible(file, robot, nom, reread)
    if is_yaml:                         # its calibration envelope, written next to it
        from kincal.robots.files import with_envelope_sidecar
        from kincal.workflow.robots import check_envelope

        robot = check_envelope(with_envelope_sidecar(robot, file))
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, (500, robot.n))
    diff = np.linalg.norm(robot.fk(q)[:, :3, 3] - nom.fk(q)[:, :3, 3], axis=1)
    kin_text = kinematics_yaml(robot, nom) if kinematics else None
    if kin_text is not None:
        _round_trip_report(out, robot, nom, kin_text)
    atomic_write_text(output, robot_yaml_text(robot))
    if kin_text is not None and kinematics:
        from kincal.robots.ur import hash_kept

        atomic_write_text(kinematics, kin_text)
        from kincal.robots.files import write_envelope_sidecar

        write_envelope_sidecar(robot, kinematics)
        _hash_note(out, kin_text, hash_kept(kin_text))
    out.print(f"{escape(Path(file).name)}: {robot.name} differs from nominal {nom.name} by "
              f"{np.sqrt(np.mean(diff ** 2)) * 1e3:.4f} mm RMS, {diff.max() * 1e3:.4f} mm max at "
              "the flange (500 random postures)")
    out.print(f"robot -> {escape(output)}" + (f"; kinematics YAML -> {escape(kinematics)}"
                                               if kinematics else ""))
    if json_out:
        from kincal.io import write_json

        write_json(json_out, {"file": file, "robot": robot.name, "nominal": nom.name,
                              "output": output, "kinematics": kinematics,
                              "flange_difference_m": {"rms": float(np.sqrt(np.mean(diff**2))),
                                                      "max": float(diff.max())}})


@app.command("ur-kinematics")
def ur_kinematics(
    robot: Annotated[str, typer.Argument(help="A calibrated UR (robot file from `kincal "
                                         "calibrate -o` or `kincal import ur`).")],
    nominal: NominalOpt,
    output: Annotated[str, typer.Option("-o", "--output", help="ROS kinematics YAML to "
                                        "write.")],
    json_out: JsonOpt = None,
) -> None:
    """Write a calibrated UR as the ROS kinematics YAML (ur_description's
    default_kinematics.yaml format), every joint origin near its nominal value."""
    from kincal.io import atomic_write_text, check_outputs
    from kincal.robots.ur import kinematics_yaml

    out = out_console(json_out)
    check_outputs({"-o": output, "--json": json_out}, {"ROBOT": [robot], "--nominal": [nominal]})
    r = serial(load(robot), "ur-kinematics")
    nom = serial(load(nominal), "ur-kinematics")
    text = kinematics_yaml(r, nom)
    _round_trip_report(out, r, nom, text)
    atomic_write_text(output, text)
    out.print(f"kinematics YAML -> {escape(output)}")
    from kincal.robots.ur import hash_kept

    _hash_note(out, text, hash_kept(text))
    from kincal.robots.files import write_envelope_sidecar

    side = write_envelope_sidecar(r, output)         # the calibration envelope travels
    if side is not None:
        out.print(f"calibration envelope -> {escape(str(side))} (keep it next to it)")
    if json_out:
        from kincal.io import write_json

        write_json(json_out, {"robot": r.name, "nominal": nom.name, "output": output})


def _hash_note(out: Console, text: str, kept: bool) -> None:
    """Say what the UR driver will make of the YAML's ``hash``."""
    import re

    m = re.search(r"^\s*hash:\s*(\S+)", text, re.MULTILINE)
    h = m.group(1) if m else "?"
    if kept:
        out.print(f"hash {escape(h)} kept from the input (unchanged calibration: the UR driver "
                  "finds it equal to the robot's checksum)")
    else:
        out.print(escape(DRIVER_NOTE.format(hash=h)))


def _speed(text: str, option: str) -> float:
    """``0.5deg/s``, ``0.01rad/s``, ``2mm/s`` -> SI per second."""
    from kincal.units import parse_quantity

    t = text.strip()
    if not t.endswith("/s"):
        raise KincalError(f"option {option}: {text!r} is not a speed with its unit "
                          "(0.5deg/s, 0.01rad/s, 2mm/s)")
    return parse_quantity(t[:-2], ("angle", "length"), option, positive=True)


@import_app.command("bag")
def import_bag(
    bag: Annotated[str, typer.Argument(help="ROS 1 .bag file, or ROS 2 bag folder (.db3 or "
                                       ".mcap storage).")],
    output: Annotated[str, typer.Option("-o", "--output", help="kincal measurement CSV to "
                                        "write.")],
    joints: Annotated[str, typer.Option("--joints", help="sensor_msgs/JointState topic.")
                      ] = "/joint_states",
    point: Annotated[str | None, typer.Option("--point", help="geometry_msgs/PointStamped "
                                              "topic of a tracked point (laser tracker).")
                     ] = None,
    pose: Annotated[str | None, typer.Option("--pose", help="geometry_msgs/PoseStamped topic "
                                             "(a tracked rigid body).")] = None,
    tf: Annotated[str | None, typer.Option("--tf", help="PARENT:CHILD frames of a /tf "
                                           "transform (e.g. mocap:tool_marker).")] = None,
    joint_names: Annotated[str | None, typer.Option("--joint-names", help="Keep only these "
                                                    "joints, comma separated (default: all "
                                                    "of the message).")] = None,
    still_speed: Annotated[str, typer.Option("--still-speed", help="A joint faster than this "
                                             "is moving.")] = "0.01rad/s",
    still_time: Annotated[str, typer.Option("--still-time", help="Shortest standstill that "
                                            "is a posture.")] = "1s",
    settle: Annotated[str, typer.Option("--settle", help="Cut from both ends of a "
                                        "standstill.")] = "0.2s",
    max_spread: Annotated[str, typer.Option("--max-spread", help="Drop a posture whose "
                                            "instrument samples spread more.")] = "1mm",
    min_samples: Annotated[int, typer.Option("--min-samples", min=1, help="Fewest instrument "
                                             "samples in a posture.")] = 3,
    name: Annotated[str, typer.Option("--name", help="Instrument name in the file.")] = "bag",
    json_out: Annotated[str | None, typer.Option("--json", help="Also write the postures "
                                                 "and the dropped ones as JSON.")] = None,
) -> None:
    """Static postures of a recorded session (ROS bag) as a kincal measurement file: the
    joint states and an instrument's stream averaged over each standstill.  Without
    --point/--pose/--tf: the standstill postures with their time windows (t0_s, t1_s), to be
    joined with the instrument's own log by time."""
    import numpy as np

    from kincal.io import atomic_write_text, check_outputs, write_json
    from kincal.measure.bags import (
        StillOptions,
        find_postures,
        measurement_text,
        postures_text,
        read_bag_streams,
    )
    from kincal.units import parse_quantity

    out = out_console(json_out)
    check_outputs({"-o": output, "--json": json_out}, {"BAG": [bag]})
    opt = StillOptions(
        still_speed=_speed(still_speed, "--still-speed"),
        still_time=parse_quantity(still_time, "time", "--still-time", positive=True),
        settle=parse_quantity(settle, "time", "--settle", minimum=0.0),
        min_samples=min_samples,
        max_spread=parse_quantity(max_spread, "length", "--max-spread", positive=True))
    names = [n.strip() for n in joint_names.split(",")] if joint_names else None
    s = read_bag_streams(bag, joints, point, pose, tf, names)
    postures, dropped = find_postures(s, opt)
    if not postures:
        raise KincalError(f"{bag}: no static posture found ({len(dropped)} standstills "
                          "dropped" + (f": {dropped[0]}" if dropped else "") + "); check "
                          "--still-speed and --still-time")
    if s.kind == "joints":
        atomic_write_text(output, postures_text(s, postures))
        out.print(f"{escape(Path(bag).name)}: {len(s.joint_t)} joint states, no instrument "
                  f"topic; {len(postures)} standstill postures with their time windows")
        for line in dropped:
            out.print(f"[yellow]dropped[/yellow] {escape(line)}")
        out.print(f"postures -> {escape(output)} (t0_s, t1_s, joints {', '.join(s.joint_names)}"
                  "): join them with the instrument's log by time (docs/tutorials/ros-bags.md)")
        if json_out:
            write_json(json_out, {"bag": bag, "output": output, "joint_names": s.joint_names,
                                  "postures": [{"t0_s": p.t0, "t1_s": p.t1, "q": p.q}
                                               for p in postures], "dropped": dropped})
        return
    atomic_write_text(output, measurement_text(s, postures, name))
    sig = np.array([p.sigma for p in postures]) * 1e3
    out.print(f"{escape(Path(bag).name)}: {len(s.joint_t)} joint states, {len(s.meas_t)} "
              f"instrument samples; {len(postures)} static postures "
              f"({np.median([p.n for p in postures]):.0f} samples each, median), sigma "
              f"{sig.min():.4f}-{sig.max():.4f} mm")
    for line in dropped:
        out.print(f"[yellow]dropped[/yellow] {escape(line)}")
    out.print(f"measurements -> {escape(output)} (joints {', '.join(s.joint_names)})")
    if json_out:
        write_json(json_out, {
            "bag": bag, "output": output, "joint_names": s.joint_names,
            "postures": [{"t0_s": p.t0, "t1_s": p.t1, "q": p.q, "position_m": p.p,
                          "sigma_m": p.sigma, "samples": p.n} for p in postures],
            "dropped": dropped})
