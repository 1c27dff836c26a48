"""Foreign layouts read as recorded: the ROS-I observation YAML and MUKCa folders with the
controller's pose files beside the socket files.

Truths: a simulated positioner whose observations are written in the ROS-I layout (the
calibration must find the known camera and target frames); the YAML numbers against
PyYAML's own parse; the MUKCa folder against the same folder without the pose files.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from kincal.errors import MeasurementFileError
from kincal.measure.artifacts.files import read_socket_folder
from kincal.measure.files import tag_overrides
from kincal.measure.rosi import read_rosi_observations
from kincal.robots.files import load_serial_robot
from kincal.workflow.sources import DataSource, detect_format, read_sources

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
if not DATA.is_dir():
    DATA = Path("/work/shared/data")
POSITIONER = ROOT / "examples" / "robots" / "rosi_positioner.yaml"


def _write_rosi(path: Path, q: np.ndarray, poses: np.ndarray) -> None:
    quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()          # x, y, z, w
    doc = {str(1000 + i): {"camera_joints": [], "target_joints": [float(v) for v in q[i]],
                           "pose": {"x": float(poses[i, 0, 3]), "y": float(poses[i, 1, 3]),
                                    "z": float(poses[i, 2, 3]), "qw": float(quat[i, 3]),
                                    "qx": float(quat[i, 0]), "qy": float(quat[i, 1]),
                                    "qz": float(quat[i, 2])}}
           for i in range(len(q))}
    path.write_text(yaml.safe_dump(doc))


def test_rosi_yaml_matches_pyyaml_and_is_detected():
    f = DATA / "rosi_positioner" / "measurements.yaml"
    if not f.exists():
        pytest.skip("ROS-I data not present")
    robot = load_serial_robot(POSITIONER)
    assert detect_format(f) == "ros-industrial"
    (b,) = read_rosi_observations(f, robot, name="camera")
    raw = yaml.safe_load(f.read_text())
    assert b.N == len(raw) == 205
    first = next(iter(raw.values()))
    np.testing.assert_array_equal(b.q[0], first["target_joints"])
    p = first["pose"]
    np.testing.assert_array_equal(b.poses[0, :3, 3], [p["x"], p["y"], p["z"]])
    want = Rotation.from_quat([p["qx"], p["qy"], p["qz"], p["qw"]]).as_matrix()
    np.testing.assert_allclose(b.poses[0, :3, :3], want, atol=1e-14)


def test_rosi_yaml_of_a_simulated_positioner_calibrates_to_its_frames(tmp_path):
    robot = load_serial_robot(POSITIONER)
    j1, j2 = np.meshgrid(np.radians(np.arange(-30, 31, 10)), np.radians(np.arange(0, 338, 45)))
    q = np.stack([j1.ravel(), j2.ravel()], axis=1)
    TI = np.eye(4)
    TI[:3, :3] = Rotation.from_euler("xyz", [10, -5, 30], degrees=True).as_matrix()
    TI[:3, 3] = [2.0, 0.7, 1.1]
    Tt = np.eye(4)
    Tt[:3, :3] = Rotation.from_euler("xyz", [90, 0, -80], degrees=True).as_matrix()
    Tt[:3, 3] = [0.17, -0.6, 0.5]
    poses = np.linalg.inv(TI) @ robot.fk(q) @ Tt
    f = tmp_path / "obs.yaml"
    _write_rosi(f, q, poses)
    (b,) = read_sources([DataSource(str(f), format="ros-industrial", name="cam",
                                    tags={"sigma_mm": "0.1"})], robot)
    assert b.sigma_position[0] == pytest.approx(1e-4)
    np.testing.assert_allclose(b.poses, poses, atol=1e-12)
    extra = b.initial_guess(robot)
    np.testing.assert_allclose(b.predict(robot, extra), poses, atol=1e-9)


@pytest.mark.parametrize("edit,msg", [
    (lambda d: d["1000"].update(camera_joints=[0.1]), "a moving camera is not supported"),
    (lambda d: d["1000"]["target_joints"].append(0.0), "3 target_joints, but the robot has 2"),
    (lambda d: d["1000"]["pose"].pop("qw"), "pose has no 'qw'"),
    (lambda d: d["1000"]["pose"].update(qw=3.0), "the quaternion's norm is"),
    (lambda d: d["1000"]["pose"].update(x="abc"), "pose.x: 'abc' is not a number")])
def test_rosi_yaml_errors_name_the_line(tmp_path, edit, msg):
    robot = load_serial_robot(POSITIONER)
    q = np.zeros((2, 2))
    f = tmp_path / "obs.yaml"
    _write_rosi(f, q, robot.fk(q))
    doc = yaml.safe_load(f.read_text())
    edit(doc)
    f.write_text(yaml.safe_dump(doc))
    with pytest.raises(MeasurementFileError, match=r"obs.yaml: line \d+: .*" + msg):
        read_rosi_observations(f, robot)


def test_mukca_folder_with_pose_files_reads_as_without_them(tmp_path):
    folder = DATA / "mukca_fleet" / "panda_7" / "front"
    if not folder.is_dir():
        pytest.skip("MUKCa data not present")
    robot = load_serial_robot(str(DATA / "panda_two_socket" / "panda.urdf"), "panda_link0",
                       "panda_hand_tcp")
    assert sorted(p.name for p in folder.glob("*_pose.csv")) == ["hole_0_pose.csv",
                                                                  "hole_1_pose.csv"]
    clean = tmp_path / "front"
    clean.mkdir()
    for f in ("hole_0.csv", "hole_1.csv"):
        shutil.copy(folder / f, clean / f)
    tags = {"length_mm": "50"}
    (a,) = read_socket_folder(folder, robot, tags)
    (b,) = read_socket_folder(clean, robot, tags)
    np.testing.assert_array_equal(a.q, b.q)
    assert list(a.socket_labels) == list(b.socket_labels)
    assert set(a.socket_labels) == {"hole_0", "hole_1"}
    n0 = sum(1 for ln in (folder / "hole_0.csv").read_text().splitlines() if ln.strip())
    assert list(a.socket_labels).count("hole_0") == n0


def test_folder_with_only_pose_files_is_refused(tmp_path):
    (tmp_path / "hole_0_pose.csv").write_text("0,0,0,0,0,0,1\n")
    robot = load_serial_robot("panda")
    with tag_overrides(tmp_path, {}), pytest.raises(MeasurementFileError,
                                                     match="no socket files"):
        read_socket_folder(tmp_path, robot, {"length_mm": "50"})


def test_mukca_robot_folder_reads_every_placement_as_one_block():
    root = DATA / "mukca_fleet" / "panda_7"
    if not root.is_dir():
        pytest.skip("MUKCa data not present")
    robot = load_serial_robot(str(DATA / "panda_two_socket" / "panda.urdf"), "panda_link0",
                       "panda_hand_tcp")
    tags = {"length_mm": "50"}
    (whole,) = read_socket_folder(root, robot, tags, name="ball")
    parts = [read_socket_folder(root / p, robot, tags)[0] for p in ("front", "right")]
    np.testing.assert_array_equal(whole.q, np.concatenate([b.q for b in parts]))
    assert list(dict.fromkeys(whole.placement_labels)) == ["front", "right"]
    assert whole.name == "ball"
