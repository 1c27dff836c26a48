"""Joint-name maps: ROS names of the built-in robots, a map in the setup file or on the
command line, and the error that lists the file's columns.

The truth is the same data written with the robot's own joint names: every spelling must
give the same joint values (rad), and a simulated robot calibrated from the ROS-named file
must find its known error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

from kincal.errors import MeasurementFileError
from kincal.measure.columns import ROS_JOINT_NAMES, format_map, parse_map
from kincal.measure.files import write_table
from kincal.measure.registry import read_measurements
from kincal.robots.files import load_serial_robot

UR = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]


def _file(tmp_path: Path, robot, names: list[str], q: np.ndarray, y: np.ndarray,
          name: str = "m.csv", factor: float = 1.0) -> Path:
    p = tmp_path / name
    head = ",".join([*names, "x_mm", "y_mm", "z_mm"])
    rows = "\n".join(",".join(f"{v:.17g}" for v in [*(qi * factor), *(yi * 1000)])
                     for qi, yi in zip(q, y, strict=True))
    p.write_text(f"# kincal measurements: instrument=position; name=lt\n{head}\n{rows}\n")
    return p


@pytest.mark.parametrize("robot_name", ["ur5", "ur10e", "panda", "kr6", "irb120"])
def test_ros_names_of_builtin_robots_read_as_their_joints(tmp_path, robot_name):
    robot = load_serial_robot(robot_name)
    rng = np.random.default_rng(1)
    q = rng.uniform(-1, 1, (5, robot.n))
    y = robot.fk(q)[:, :3, 3]
    ros = list(ROS_JOINT_NAMES[robot_name])
    assert [ROS_JOINT_NAMES[robot_name][r] for r in ros] == [j.name for j in robot.joints]
    native = _file(tmp_path, robot, [f"{j.name}_rad" for j in robot.joints], q, y, "a.csv")
    ros_file = _file(tmp_path, robot, ros, q, y, "b.csv")
    ref = read_measurements(native, robot)[0]
    (b,) = read_measurements(ros_file, robot)
    np.testing.assert_array_equal(b.q, ref.q)
    np.testing.assert_allclose(b.q, q, rtol=0, atol=1e-15)
    assert any("ROS joint names" in n for n in b.provenance.table.notes)


def test_ros_name_with_a_unit_suffix_keeps_its_unit(tmp_path):
    robot = load_serial_robot("ur5")
    q = np.array([[10.0, -20, 30, -40, 50, -60]])
    p = _file(tmp_path, robot, [f"{j}_joint_deg" for j in UR], np.radians(q),
              robot.fk(np.radians(q))[:, :3, 3], factor=180 / np.pi)
    (b,) = read_measurements(p, robot)
    np.testing.assert_allclose(np.degrees(b.q), q, rtol=1e-13)


def test_six_columns_with_other_names_list_what_was_found_and_expected(tmp_path):
    robot = load_serial_robot("ur5")
    q = np.zeros((2, 6))
    names = [f"axis_{c}" for c in "abcdef"]
    p = _file(tmp_path, robot, names, q, robot.fk(q)[:, :3, 3])
    with pytest.raises(MeasurementFileError) as exc:
        read_measurements(p, robot)
    msg = str(exc.value)
    assert "line 2: no column for joint 'shoulder_pan'" in msg
    assert "its columns are: axis_a, axis_b, axis_c, axis_d, axis_e, axis_f, x_mm" in msg
    assert "shoulder_pan, shoulder_lift, elbow, wrist_1, wrist_2, wrist_3" in msg
    assert "--joint-names 'shoulder_pan_joint=shoulder_pan,...'" in msg
    assert "\n" not in msg
    p = _file(tmp_path, robot, [f"J{i}" for i in range(1, 7)], q, robot.fk(q)[:, :3, 3])
    with pytest.raises(MeasurementFileError, match=r"column 1 \(J1\) looks like a joint "
                       r"column.*map it with --joint-names"):
        read_measurements(p, robot, units={"J?": "rad"})


def test_a_map_renames_joint_columns_with_units_on_either_name(tmp_path):
    robot = load_serial_robot("ur5")
    rng = np.random.default_rng(2)
    q = rng.uniform(-1, 1, (4, 6))
    p = _file(tmp_path, robot, [f"J{i}" for i in range(1, 7)], q, robot.fk(q)[:, :3, 3])
    mapping = format_map({f"J{i + 1}": j for i, j in enumerate(UR)})
    (b,) = read_measurements(p, robot, units={"J?": "rad"}, tags={"joint_names": mapping})
    np.testing.assert_allclose(b.q, q, rtol=0, atol=1e-15)
    mapping = format_map({f"J{i + 1}": f"{j}_rad" for i, j in enumerate(UR)})
    (c,) = read_measurements(p, robot, tags={"joint_names": mapping})
    np.testing.assert_array_equal(c.q, b.q)


def test_bad_maps_are_one_line_naming_what_there_is(tmp_path):
    robot = load_serial_robot("ur5")
    q = np.zeros((1, 6))
    p = _file(tmp_path, robot, [f"J{i}" for i in range(1, 7)], q, robot.fk(q)[:, :3, 3])
    with pytest.raises(MeasurementFileError, match=r"joint_names: the file has no column 'J9'"
                       r" \(columns: J1, J2"):
        read_measurements(p, robot, tags={"joint_names": "J9=shoulder_pan"})
    with pytest.raises(MeasurementFileError, match=r"robot 'ur5' has no joint 'q1' \(joints: "
                       "shoulder_pan"):
        read_measurements(p, robot, tags={"joint_names": "J1=q1"})
    with pytest.raises(MeasurementFileError, match="joint_names ros: robot 'puma560' has no "
                       "known ROS joint names"):
        read_measurements(p, load_serial_robot("puma560"), tags={"joint_names": "ros"})
    with pytest.raises(MeasurementFileError, match="is not FILE_COLUMN=NAME"):
        parse_map("J1")
    assert parse_map("a=b, c=d") == {"a": "b", "c": "d"}


def test_cli_joint_names_calibrates_a_simulated_robot(tmp_path, capsys):
    """A UR5 with a known offset error on the elbow, measured into a file whose joints
    are J1..J6 in deg: --joint-names maps them and the fit finds the error."""
    nominal = load_serial_robot("ur5")
    true_offset = nominal.params()["theta_offset[3]"] + np.radians(0.2)
    truth = nominal.with_params({"theta_offset[3]": true_offset})
    rng = np.random.default_rng(3)
    q = rng.uniform(-2, 2, (60, 6))
    y = truth.fk(q)[:, :3, 3]
    f = tmp_path / "j.csv"
    write_table(f, q, [(c, y[:, i], "length") for i, c in enumerate("xyz")], robot=nominal,
                tags={"instrument": "position", "name": "lt"}, angle_unit="deg",
                length_unit="mm")
    text = f.read_text()
    for i, j in enumerate(UR):
        text = text.replace(f"{j}_deg", f"J{i + 1}_deg")
    f.write_text(text)
    code, out, err = run(capsys, "calibrate", "ur5", "--data", f, "--json", tmp_path / "r.json",
                         "--free", "theta_offset[3]", "--prior", "none")
    assert code == 2 and "(J1_deg) looks like a joint column" in err and "--joint-names" in err
    mapping = ",".join(f"J{i + 1}_deg={j}_deg" for i, j in enumerate(UR))
    code, out, err = run(capsys, "calibrate", "ur5", "--data", f, "--json", tmp_path / "r.json",
                         "--free", "theta_offset[3],lt.*", "--prior", "none",
                         "--joint-names", mapping)
    assert code == 0, err
    import json

    res = json.loads((tmp_path / "r.json").read_text())
    est = next(p["estimate"] for p in res["parameters"] if p["name"] == "theta_offset[3]")
    assert est == pytest.approx(true_offset, abs=1e-9)
    assert "joint columns mapped: J1_deg -> shoulder_pan_deg" in " ".join((out + err).split())


def test_setup_file_maps_as_a_mapping_or_ros_and_only_for_csv_files(tmp_path):
    from kincal.workflow.config import SetupError, parse_setup

    (tmp_path / "m.csv").write_text("J1,x_mm\n0,1\n")
    (tmp_path / "sockets").mkdir()
    ok = parse_setup({"robot": "ur5", "data": [
        {"file": "m.csv", "joint_names": {"J1": "shoulder_pan"},
         "columns": {"x_mm": "x_mm"}},
        {"file": "m.csv", "joint_names": "ros"}]}, tmp_path)
    assert ok.data[0].tags["joint_names"] == "J1=shoulder_pan"
    assert ok.data[0].tags["columns"] == "x_mm=x_mm"
    assert ok.data[1].tags["joint_names"] == "ros"
    with pytest.raises(SetupError, match=r"data\[0\]\.joint_names: maps the columns of a CSV"):
        parse_setup({"robot": "ur5", "data": [{"file": "sockets", "joint_names": {"a": "b"}}]},
                    tmp_path)
    with pytest.raises(SetupError, match=r"data\[0\]\.columns: column name 'a,b'"):
        parse_setup({"robot": "ur5", "data": [{"file": "m.csv", "columns": {"a,b": "x"}}]},
                    tmp_path)
