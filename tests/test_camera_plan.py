"""`kincal plan --camera`: poses that see the whole board, chosen D-optimally; checked by
projecting the corners, by a Monte Carlo of simulated captures at the planned poses and
against random visible poses."""

from __future__ import annotations

import numpy as np
import pytest

from kincal.identify.camera_plan import plan_camera_poses
from kincal.identify.hand_eye_fit import fit_hand_camera
from kincal.measure.camera_board import Board
from kincal.measure.instruments.camera import HandCameraMeasurement
from kincal.robots.files import load_serial_robot
from kincal.spatial import inverse, matrix_from_frame

BOARD = Board("charuco", 4, 5, 0.04, 0.03, "DICT_6X6_250")
K = (640.0, 641.0, 645.0, 355.0)
SIZE = (1280, 720)
Q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])


@pytest.fixture(scope="module")
def robot():
    return load_serial_robot("panda")


@pytest.fixture(scope="module")
def hand_plan(robot):
    return plan_camera_poses(robot, BOARD.corner_points(np.arange(BOARD.num_corners)), K, SIZE,
                             "hand", 10, ["theta_offset*"], center=Q0, candidates=300,
                             spread=np.radians(25), X=matrix_from_frame([0.04, -0.03, 0.06,
                                                                         0.8, 0.0, 0.0]))


def _pixels(robot, q, X, Z, mount):
    pts = BOARD.corner_points(np.arange(BOARD.num_corners))
    out = []
    for T in robot.fk(q):
        B = inverse(T @ X) @ Z if mount == "hand" else inverse(X) @ T @ Z
        x = pts @ B[:3, :3].T + B[:3, 3]
        out.append(np.column_stack([K[0] * x[:, 0] / x[:, 2] + K[2],
                                    K[1] * x[:, 1] / x[:, 2] + K[3]]))
    return pts, np.array(out), x


@pytest.mark.parametrize("mount", ["hand", "fixed"])
def test_every_planned_pose_sees_the_whole_board(robot, hand_plan, mount) -> None:
    """Project the corners independently: all inside the image (5 % margin), in front,
    the board's normal within 45 deg of the ray from the camera, its printed face seen."""
    p = hand_plan if mount == "hand" else plan_camera_poses(
        robot, BOARD.corner_points(np.arange(BOARD.num_corners)), K, SIZE, "fixed", 8,
        ["theta_offset*"], center=Q0, candidates=200, spread=np.radians(25))
    assert len(p.q) == (10 if mount == "hand" else 8)
    pts, uv, _ = _pixels(robot, p.q, p.X, p.Z, mount)
    assert np.all((uv[..., 0] >= 0.05 * SIZE[0]) & (uv[..., 0] <= 0.95 * SIZE[0]))
    assert np.all((uv[..., 1] >= 0.05 * SIZE[1]) & (uv[..., 1] <= 0.95 * SIZE[1]))
    for T in robot.fk(p.q):
        B = inverse(T @ p.X) @ p.Z if mount == "hand" else inverse(p.X) @ T @ p.Z
        c = B[:3, :3] @ pts.mean(axis=0) + B[:3, 3]
        assert c[2] > 0.05
        # OpenCV's board z points into the board: away from a camera that sees its face
        assert np.degrees(np.arccos(B[:3, 2] @ c / np.linalg.norm(c))) <= 45.0 + 1e-9
    assert set(p.not_identifiable) == {"theta_offset[1]", "theta_offset[7]"}


def test_plan_beats_random_visible_poses(hand_plan) -> None:
    """The D-optimal plan's predicted hand-eye errors are below the median of 20 random
    designs of the same size from the same visible candidates."""
    pos, rot = hand_plan.median_random
    assert hand_plan.std_position < pos and hand_plan.std_rotation < rot


def test_predicted_errors_match_a_monte_carlo_of_captures(robot, hand_plan) -> None:
    """8 simulated capture sets at the planned poses (0.5 px), each fitted with the joint
    offsets free: the RMS hand-eye position and rotation errors are the predicted ones
    (ratio within 0.55..1.6 for about 24 squared errors each)."""
    p = hand_plan
    pts, uv, _ = _pixels(robot, p.q, p.X, p.Z, "hand")
    rng = np.random.default_rng(3)
    labels = np.repeat([f"{k:02d}" for k in range(len(p.q))], len(pts))
    e_pos, e_rot = [], []
    for _ in range(8):
        noisy = uv + rng.normal(0.0, 0.5, uv.shape)
        block = HandCameraMeasurement("camera", np.repeat(p.q, len(pts), axis=0),
                                      np.tile(pts, (len(p.q), 1)), noisy.reshape(-1, 2), 0.5,
                                      K)
        fit = fit_hand_camera(robot, block, labels, holdout=0.0, free=["theta_offset*"],
                              min_rotation_deg=0.0)
        e_pos.append(np.linalg.norm(fit.X[:3, 3] - p.X[:3, 3]))
        R = fit.X[:3, :3] @ p.X[:3, :3].T
        e_rot.append(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    ratio_p = np.sqrt(np.mean(np.square(e_pos))) / p.std_position
    ratio_r = np.sqrt(np.mean(np.square(e_rot))) / p.std_rotation
    assert 0.55 < ratio_p < 1.6 and 0.55 < ratio_r < 1.6, (ratio_p, ratio_r)


CAMERA_INFO = ("image_width: 1280\nimage_height: 720\ncamera_matrix: {rows: 3, cols: 3, data: "
               "[640, 0, 645, 0, 641, 355, 0, 0, 1]}\ndistortion_coefficients: {rows: 1, cols: 5,"
               " data: [0, 0, 0, 0, 0]}\n")


def test_cli_writes_the_joints_csv_import_images_reads(tmp_path, capsys) -> None:
    """`kincal plan --camera fixed`: the CSV is what `import images --joints` reads (the
    JSON's poses), the hand-eye error is printed; bad options refused in one line."""
    import json

    from cli_helpers import run

    from kincal.measure.camera_images import read_joints_csv

    (tmp_path / "board.yaml").write_text("type: charuco\nsquares: [4, 5]\nsquare: 40mm\n"
                                         "marker: 30mm\ndictionary: DICT_6X6_250\n")
    (tmp_path / "cam.yaml").write_text(CAMERA_INFO)
    args = ["plan", "panda", "--camera", "fixed", "--board", tmp_path / "board.yaml",
            "--intrinsics", tmp_path / "cam.yaml", "--center", "0,-17,0,-115,0,103,46",
            "--spread", "25deg", "--candidates", "200", "-n", "6", "--angle-unit", "deg"]
    code, out, err = run(capsys, *args, "-o", tmp_path / "p.csv", "--json", tmp_path / "p.json")
    assert code == 0, err
    assert "predicted hand-eye error" in out and "see the whole board" in out
    doc = json.loads((tmp_path / "p.json").read_text())
    q = read_joints_csv(tmp_path / "p.csv")
    assert list(q) == doc["images"] and len(q) == 6
    assert np.allclose(np.array(list(q.values())), doc["poses"], atol=1e-7)
    for extra, match in [(["--camera", "wrist"], "--camera"),
                         (["--camera", "hand", "--image-size", "big"], "--image-size"),
                         (["--camera", "hand", "-n", "150"], "see the whole board"),
                         (["--program", "krl"], "--program: not with --camera")]:
        code, out, err = run(capsys, *args, *extra, "-o", tmp_path / "x.csv")
        assert code == 2 and err.count("\n") == 1 and match in err, err
        assert not (tmp_path / "x.csv").exists()


def test_opencv_finds_every_corner_in_images_rendered_at_planned_poses(robot, hand_plan
                                                                        ) -> None:
    """Independent of the plan's own projection: the board rendered (perspective warp of
    the printed board, blur, noise) at three planned poses is detected by OpenCV (8-11 of
    the 12 corners: ChArUco's interpolation drops some at the edges; a mirrored board, its
    back seen, gives none) at the planned pixels (0.04 px), so the printed face is seen."""
    cv2 = pytest.importorskip("cv2")
    from test_camera_images import MARGIN, PX, _render

    from kincal.measure.camera_images import detect_board

    Kt = np.array([[K[0], 0, K[2]], [0, K[1], K[3]], [0, 0, 1]])
    S = np.array([[PX / BOARD.square, 0, MARGIN - 0.5], [0, PX / BOARD.square, MARGIN - 0.5],
                  [0, 0, 1]])
    pts, uv, _ = _pixels(robot, hand_plan.q[:3], hand_plan.X, hand_plan.Z, "hand")
    rng = np.random.default_rng(0)
    for T, u in zip(robot.fk(hand_plan.q[:3]), uv, strict=True):
        B = inverse(T @ hand_plan.X) @ hand_plan.Z
        H = Kt @ np.column_stack([B[:3, 0], B[:3, 1], B[:3, 3]]) @ np.linalg.inv(S)
        ids, found = detect_board(cv2, _render(cv2, BOARD, H / H[2, 2], rng), BOARD)
        assert len(ids) >= 8
        assert np.abs(found - u[ids]).max() < 1.0
