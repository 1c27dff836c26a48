"""What ``kincal hand-eye`` writes for ROS and for people, read back independently.

One run on rendered images (a fixed camera watching a ChArUco board on the flange, as in
``test_camera_lens``) writes every file; each is parsed with ``yaml`` / ``xml.etree`` and
the transform recomposed here with NumPy (quaternion and URDF rpy formulas written out),
compared with the fitted matrix of the JSON; the camera_info is re-read by kincal's own
intrinsics reader; the report's table and pictures are checked against the fit.
"""

from __future__ import annotations

import base64
import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_helpers import invoke, run

from kincal.measure.camera_board import Board
from kincal.report.ros_camera import static_transform_launch, urdf_joint
from kincal.spatial import inverse, matrix_from_frame

BOARD = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")


def _quat_matrix(qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """R of a unit quaternion (Hamilton, scalar last as ROS writes it)."""
    return np.array([
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])


def _rpy_matrix(r: float, p: float, y: float) -> np.ndarray:
    """URDF's rpy: R = Rz(y) Ry(p) Rx(r)."""
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return Rz @ Ry @ Rx


def _T(t, R) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """9 rendered images (1280 x 720), flange poses, one ``kincal hand-eye`` run writing
    every output."""
    cv2 = pytest.importorskip("cv2")
    from test_camera_lens import render_fixed_camera_set

    d = tmp_path_factory.mktemp("outputs")
    render_fixed_camera_set(cv2, d, np.random.default_rng(5))
    code = invoke("hand-eye", "--images", d / "img", "--board", d / "board.yaml", "--poses",
                  d / "poses", "--mount", "fixed", "--lens", "pinhole",
                  "--ros-yaml", d / "he.yaml", "--ros-launch", d / "he.launch",
                  "--urdf-joint", d / "he.urdf", "--camera-info", d / "ci.yaml",
                  "--report", d / "r.html", "--json", d / "f.json", "--parent-frame", "world")
    assert code == 0
    return d


def test_easy_handeye_yaml_recomposes_the_fit(run_dir: Path) -> None:
    fit = json.loads((run_dir / "f.json").read_text())
    doc = yaml.safe_load((run_dir / "he.yaml").read_text())
    p = doc["parameters"]
    assert p["eye_on_hand"] is False and p["robot_base_frame"] == "world"
    assert p["tracking_base_frame"] == "camera_optical_frame"
    tr = doc["transformation"]
    q = np.array([tr[k] for k in ("qx", "qy", "qz", "qw")])
    assert abs(np.linalg.norm(q) - 1) < 1e-12
    T = _T([tr["x"], tr["y"], tr["z"]], _quat_matrix(*q))
    assert np.abs(T - np.array(fit["camera"]["matrix"])).max() < 1e-12


def test_launch_file_publishes_the_fit(run_dir: Path) -> None:
    fit = np.array(json.loads((run_dir / "f.json").read_text())["camera"]["matrix"])
    node = ET.parse(run_dir / "he.launch").getroot().find("node")
    assert node is not None and node.get("pkg") == "tf2_ros"
    assert node.get("type") == "static_transform_publisher"
    args = node.get("args", "").split()
    assert args[7:] == ["world", "camera_optical_frame"]
    v = [float(a) for a in args[:7]]
    assert np.abs(_T(v[:3], _quat_matrix(*v[3:])) - fit).max() < 1e-12
    # ROS 2's XML form: exec= and named arguments
    root = ET.fromstring(static_transform_launch(fit, "tool0", "cam", ros2=True))
    n2 = root.find("node")
    assert n2 is not None and n2.get("exec") == "static_transform_publisher"
    a2 = n2.get("args", "").split()
    named = dict(zip(a2[::2], a2[1::2], strict=True))
    assert named["--frame-id"] == "tool0" and named["--child-frame-id"] == "cam"
    v2 = [float(named[k]) for k in ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw")]
    assert np.abs(_T(v2[:3], _quat_matrix(*v2[3:])) - fit).max() < 1e-12


def _urdf_matrix(text: str) -> tuple[np.ndarray, ET.Element]:
    joint = ET.fromstring(text).find("joint")
    assert joint is not None and joint.get("type") == "fixed"
    origin = joint.find("origin")
    assert origin is not None
    xyz = [float(v) for v in origin.get("xyz", "").split()]
    rpy = [float(v) for v in origin.get("rpy", "").split()]
    return _T(xyz, _rpy_matrix(*rpy)), joint


def test_urdf_joint_recomposes_the_fit(run_dir: Path) -> None:
    fit = np.array(json.loads((run_dir / "f.json").read_text())["camera"]["matrix"])
    T, joint = _urdf_matrix((run_dir / "he.urdf").read_text())
    assert joint.find("parent").get("link") == "world"                    # type: ignore[union-attr]
    assert joint.find("child").get("link") == "camera_optical_frame"     # type: ignore[union-attr]
    assert np.abs(T - fit).max() < 1e-12
    # at gimbal lock (pitch 90 deg) the joint still gives the same matrix
    lock = matrix_from_frame([0.1, -0.2, 0.3, 0.7, np.pi / 2, -0.4])
    assert np.abs(_urdf_matrix(urdf_joint(lock, "a", "b"))[0] - lock).max() < 1e-12


def test_camera_info_reads_back_as_the_fitted_intrinsics(run_dir: Path) -> None:
    from kincal.measure.camera_images import read_intrinsics

    fit = json.loads((run_dir / "f.json").read_text())["intrinsics"]
    doc = yaml.safe_load((run_dir / "ci.yaml").read_text())
    assert (doc["image_width"], doc["image_height"]) == (1280, 720)
    assert doc["distortion_model"] == "plumb_bob" and doc["camera_name"]
    K = np.array(doc["camera_matrix"]["data"]).reshape(3, 3)
    P = np.array(doc["projection_matrix"]["data"]).reshape(3, 4)
    assert np.array_equal(P[:, :3], K) and not P[:, 3].any()
    assert np.array_equal(np.array(doc["rectification_matrix"]["data"]), np.eye(3).ravel())
    intr = read_intrinsics(run_dir / "ci.yaml")
    assert (intr.fx, intr.fy, intr.cx, intr.cy) == (fit["fx"], fit["fy"], fit["cx"], fit["cy"])
    assert intr.dist == tuple(fit[k] for k in ("k1", "k2", "p1", "p2", "k3"))


def test_report_lists_images_worst_first_with_the_fits_numbers(run_dir: Path) -> None:
    cv2 = pytest.importorskip("cv2")
    fit = json.loads((run_dir / "f.json").read_text())
    page = (run_dir / "r.html").read_text()
    rows = re.findall(r"<tr><td class='l'>([^<]+)</td><td class='l'>(training|held out)</td>"
                      r"<td>(\d+)</td><td>([\d.]+)</td><td>([\d.]+)</td></tr>", page)
    assert len(rows) == 9
    rms = [float(r[3]) for r in rows]
    assert rms == sorted(rms, reverse=True)
    held = {r[0]: float(r[3]) for r in rows if r[1] == "held out"}
    assert set(held) == set(fit["held_out"])
    for name, v in fit["held_out_per_image_px"].items():
        assert abs(held[name] - v) <= 6e-4
    train = [(int(r[2]), float(r[3])) for r in rows if r[1] == "training"]
    pooled = np.sqrt(sum(n * e**2 for n, e in train) / sum(n for n, _ in train))
    assert abs(pooled - fit["reprojection_rms_px"]["training"]) < 2e-3
    pngs = re.findall(r'<img alt="([^"]+)" src="data:image/png;base64,([^"]+)"', page)
    assert [n for n, _ in pngs] == [r[0] for r in rows[:4]]        # the 4 worst, in order
    for _, data in pngs:
        img = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (720, 1280, 3)


def test_bad_output_paths_and_options_are_refused_before_any_work(run_dir: Path, capsys,
                                                                  tmp_path: Path) -> None:
    base = ["hand-eye", "--images", run_dir / "img", "--board", run_dir / "board.yaml",
            "--poses", run_dir / "poses", "--mount", "fixed", "--json", tmp_path / "f.json"]
    for extra, match in [
            (["--ros-yaml", tmp_path / "no" / "he.yaml"], "--ros-yaml: the folder"),
            (["--report", run_dir / "board.yaml"], "--report: .* is also the input of --board"),
            (["--urdf-joint", tmp_path], "--urdf-joint: .* is a folder"),
            (["--camera-info", tmp_path / "a.yaml", "--ros-yaml", tmp_path / "a.yaml"],
             "name the same file"),
            (["--child-frame", "my camera"], "--child-frame: 'my camera' is not a ROS frame"),
            (["--parent-frame", "1base"], "--parent-frame")]:
        code, out, err = run(capsys, *base, *extra)
        assert code == 2 and err.count("\n") == 1 and re.search(match, err), err
        assert out == "" and not (tmp_path / "f.json").exists()
    # the camera_info and the pictures need the images
    for opt in ("--camera-info", "--report"):
        code, out, err = run(capsys, "hand-eye", "panda", "--data", tmp_path / "x.csv", opt,
                             tmp_path / "o")
        assert code == 2 and f"{opt}: needs --images" in err, err


def test_closed_form_does_not_depend_on_the_order_with_noise() -> None:
    """With noisy poses a pair and its reverse give different translation equations; the
    closed form uses both, so a shuffle changes nothing (benchmarks/hand_eye.py found
    0.08 mm with one orientation per pair)."""
    from kincal.identify.hand_eye import hand_eye
    from kincal.spatial import exp_so3

    rng = np.random.default_rng(2)
    X = matrix_from_frame([0.04, -0.03, 0.065, 0.8, 0.01, -0.05])
    Z = matrix_from_frame([0.5, 0.1, 0.0, 0.3, 0.0, np.pi])
    A = np.array([matrix_from_frame(np.r_[rng.uniform(-0.1, 0.1, 3) + [0.5, 0.1, 0.5],
                                          rng.uniform(-0.6, 0.6, 3)]) for _ in range(12)])
    B = inverse(X) @ inverse(A) @ Z
    noisy = B.copy()
    noisy[:, :3, :3] = exp_so3(rng.normal(0, 2e-3, (12, 3))) @ B[:, :3, :3]
    noisy[:, :3, 3] += rng.normal(0, 1e-3, (12, 3))
    a = hand_eye(A, noisy).X
    assert np.linalg.norm(a[:3, 3] - X[:3, 3]) > 1e-4           # the noise moved it
    for seed in range(3):
        p = np.random.default_rng(seed).permutation(12)
        assert np.abs(hand_eye(A[p], noisy[p]).X - a).max() < 1e-9


def test_hand_camera_from_a_measurement_file_writes_its_transform(tmp_path: Path,
                                                                  capsys) -> None:
    """``--data`` (camera on the hand): the files hold the camera in the tool frame, what
    the JSON states, under the default frame names tool0 -> camera_optical_frame."""
    from test_camera_hand_eye import _write, simulate

    from kincal.robots.files import load_serial_robot

    block, labels, _ = simulate(load_serial_robot("panda"), 8, 0.3, np.random.default_rng(4))
    _write(tmp_path / "d.csv", block, labels)
    code, out, err = run(capsys, "hand-eye", "panda", "--data", tmp_path / "d.csv",
                         "--ros-yaml", tmp_path / "he.yaml", "--urdf-joint", tmp_path / "j.urdf",
                         "--json", tmp_path / "f.json")
    assert code == 0, err
    fit = np.array(json.loads((tmp_path / "f.json").read_text())
                   ["camera_in_tool_frame"]["matrix"])
    doc = yaml.safe_load((tmp_path / "he.yaml").read_text())
    assert doc["parameters"]["eye_on_hand"] is True
    assert doc["parameters"]["robot_effector_frame"] == "tool0"
    tr = doc["transformation"]
    T = _T([tr["x"], tr["y"], tr["z"]], _quat_matrix(*(tr[k] for k in ("qx", "qy", "qz",
                                                                         "qw"))))
    assert np.abs(T - fit).max() < 1e-12
    U, joint = _urdf_matrix((tmp_path / "j.urdf").read_text())
    assert joint.find("parent").get("link") == "tool0"                   # type: ignore[union-attr]
    assert np.abs(U - fit).max() < 1e-12
