"""Hand-eye and intrinsics in one fit, from raw (distorted) pixels: known truth.

A camera with a known lens (focal lengths, principal point and OpenCV radial-tangential
distortion, about a RealSense's) on the flange of a simulated Panda, or fixed and watching
a board on the flange; pixels are the exact projection through that lens plus Gaussian
noise; everything is recovered from them, the fit starting from the pinhole without
distortion (the ABB set's situation).
"""

from __future__ import annotations

import numpy as np
import pytest

from kincal.errors import IdentifiabilityError, KincalError
from kincal.identify.hand_eye_lens import (
    calibrate_board_camera,
    fit_board_camera,
    project_lens,
    undistort_pixels,
)
from kincal.measure.camera_board import Board
from kincal.robots.files import load_serial_robot
from kincal.spatial import inverse, log_so3, matrix_from_frame

BOARD = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
LENS = np.array([640.0, 641.0, 645.0, 355.0, -0.12, 0.09, 0.001, -0.0015, -0.03])
SIZE = (1280, 720)
Q0 = np.array([-0.22, -0.19, 0.0, -2.42, 0.28, 2.15, 0.31])
X_HAND = matrix_from_frame([0.040, -0.030, 0.065, 0.80, 0.01, -0.05])


def _seen(B: np.ndarray, pts: np.ndarray, lens: np.ndarray = LENS) -> np.ndarray | None:
    x = pts @ B[:3, :3].T + B[:3, 3]
    if np.any(x[:, 2] < 0.1):
        return None
    uv = project_lens(x, lens)
    inside = (uv[:, 0] > 5) & (uv[:, 0] < SIZE[0] - 5) & (uv[:, 1] > 5) & (uv[:, 1] < SIZE[1] - 5)
    return uv if inside.all() else None


def simulate_hand(n: int, noise: float, rng: np.random.Generator, spread: float = 0.3,
                  joint_error: float = 0.0):
    """``n`` images of the board from the hand camera; ``joint_error`` [rad]: each image
    taken with the joints that far (per joint, standard deviation) from the ones stated."""
    robot = load_serial_robot("panda")
    pts = BOARD.corner_points(np.arange(BOARD.num_corners))
    Z = robot.fk(Q0) @ X_HAND @ matrix_from_frame([-0.07, -0.10, 0.36, 0.3, 0.1, -0.1])
    A, uv = [], []
    while len(A) < n:
        q = Q0 + rng.uniform(-spread, spread, 7)
        T = robot.fk(q + rng.normal(0.0, joint_error, 7))
        p = _seen(inverse(X_HAND) @ inverse(T) @ Z, pts)
        if p is not None:
            A.append(robot.fk(q))
            uv.append(p + rng.normal(0.0, noise, p.shape))
    return np.array(A), [pts] * n, uv, Z


def _rot(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.linalg.norm(log_so3(A[:3, :3] @ B[:3, :3].T)))


def test_projection_is_opencvs() -> None:
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(0)
    x = np.column_stack([rng.uniform(-0.3, 0.3, (50, 2)), rng.uniform(0.4, 1.0, 50)])
    K = np.array([[LENS[0], 0, LENS[2]], [0, LENS[1], LENS[3]], [0, 0, 1]])
    ref = cv2.projectPoints(x, np.zeros(3), np.zeros(3), K, LENS[4:])[0].reshape(-1, 2)
    assert np.abs(project_lens(x, LENS) - ref).max() < 1e-9
    # undistorting gives the pinhole pixels of the same points
    pin = project_lens(x, np.r_[LENS[:4], np.zeros(5)])
    assert np.abs(undistort_pixels(ref, LENS) - pin).max() < 1e-6


def test_distortion_and_hand_eye_recovered_together() -> None:
    """16 images, 0.3 px: every intrinsic within 4 of its standard errors, the hand-eye
    within 4 expected errors; the held-out images at the noise (sqrt(2) 0.3 px per
    corner); the pinhole alone (distortion not fitted) is many times worse."""
    A, pts, uv, Z = simulate_hand(16, 0.3, np.random.default_rng(1))
    names = [f"img_{k:02d}" for k in range(16)]
    start = np.r_[LENS[:4] * [1.02, 1.02, 1.0, 1.0] + [0, 0, 8, -6], np.zeros(5)]
    fit = calibrate_board_camera(A, pts, uv, names, start, "hand", holdout=0.25, sigma=0.3)
    assert np.all(np.abs(fit.lens - LENS) < 4 * fit.lens_std), (fit.lens - LENS) / fit.lens_std
    assert np.linalg.norm(fit.X[:3, 3] - X_HAND[:3, 3]) < 4 * fit.expected_position
    assert _rot(fit.X, X_HAND) < 4 * fit.expected_rotation
    assert np.linalg.norm(fit.Z[:3, 3] - Z[:3, 3]) < 5e-3
    assert 0.3 < fit.held_rms_px < 0.3 * np.sqrt(2) * 1.5
    pinhole = calibrate_board_camera(A, pts, uv, names, start, "hand", holdout=0.25,
                                     sigma=0.3, fit_lens=("fx", "fy", "cx", "cy"))
    assert pinhole.held_rms_px > 5 * fit.held_rms_px


def test_lens_hand_eye_and_joint_offsets_in_one_fit() -> None:
    """A Panda with joint offsets off nominal (0.4-0.7 deg, as the Franka set's), the lens
    distorted, 16 images: the offsets the images identify, the lens and the hand-eye all
    within 4 standard errors; the held-out images at the noise."""
    nominal = load_serial_robot("panda")
    offsets = dict(zip([f"theta_offset[{k}]" for k in range(2, 7)],
                       [-0.009, -0.0126, -0.0064, 0.0126, -0.0085], strict=True))
    true = nominal.with_params(offsets)
    rng = np.random.default_rng(21)
    pts = BOARD.corner_points(np.arange(24))
    Z = true.fk(Q0) @ X_HAND @ matrix_from_frame([-0.07, -0.10, 0.36, 0.3, 0.1, -0.1])
    q, uv = [], []
    while len(q) < 16:
        qi = Q0 + rng.uniform(-0.35, 0.35, 7)
        p = _seen(inverse(X_HAND) @ inverse(true.fk(qi)) @ Z, pts)
        if p is not None:
            q.append(qi)
            uv.append(p + rng.normal(0.0, 0.3, p.shape))
    q = np.array(q)
    names = [f"{k:02d}" for k in range(16)]
    fit = calibrate_board_camera(nominal.fk(q), [pts] * 16, uv, names,
                                 np.r_[LENS[:4], np.zeros(5)], "hand", 0.25, sigma=0.3,
                                 robot=nominal, q=q, free=["theta_offset*"])
    assert set(fit.robot) == set(offsets)          # the ones the images identify
    for n, (v, s) in fit.robot.items():
        assert abs(v - offsets[n]) < 4 * s, n
    assert np.all(np.abs(fit.lens - LENS) < 4 * fit.lens_std)
    assert np.linalg.norm(fit.X[:3, 3] - X_HAND[:3, 3]) < 4 * fit.expected_position
    assert fit.held_rms_px < 0.3 * np.sqrt(2) * 1.5


def test_eye_to_hand_with_distortion_and_order_free() -> None:
    """A fixed camera, the board on the flange, flange poses only (no joints), 10 images:
    the camera in the base and the lens recovered; shuffling the images changes nothing."""
    rng = np.random.default_rng(5)
    camera = matrix_from_frame([0.0, 1.27, 0.28, -1.6, 0.1, -2.0])
    board = matrix_from_frame([0.06, 0.12, 0.21, 0.5, 0.2, 0.3])
    pts = BOARD.corner_points(np.arange(24))
    A, uv = [], []
    while len(A) < 10:
        seen = matrix_from_frame(np.r_[rng.uniform(-0.15, 0.15, 2), rng.uniform(0.45, 0.7),
                                       rng.uniform(-0.5, 0.5, 2), np.pi + rng.uniform(-.5, .5)])
        p = _seen(seen, pts)
        if p is not None:
            A.append(camera @ seen @ inverse(board))
            uv.append(p + rng.normal(0.0, 0.3, p.shape))
    A = np.array(A)
    names = [f"{k}" for k in range(10)]
    start = np.r_[LENS[:4], np.zeros(5)]
    fit = calibrate_board_camera(A, [pts] * 10, uv, names, start, "fixed", holdout=0.0,
                                 sigma=0.3)
    assert np.linalg.norm(fit.X[:3, 3] - camera[:3, 3]) < 4 * fit.expected_position
    assert np.all(np.abs(fit.lens - LENS) < 4 * fit.lens_std)
    p = rng.permutation(10)
    again = calibrate_board_camera(A[p], [pts] * 10, [uv[k] for k in p], [names[k] for k in p],
                                   start, "fixed", holdout=0.0, sigma=0.3)
    assert np.abs(again.X - fit.X).max() < 1e-7 and np.abs(again.lens - fit.lens).max() < 1e-5


def test_expected_error_is_honest_with_the_lens_fitted() -> None:
    """Monte Carlo over 10 sets of 12 images (0.3 px, and 0.1 deg of joint error per joint
    and image that nothing models): true hand-eye error / expected error RMS in 1/1.5..1.5."""
    ratios = []
    for seed in range(10):
        A, pts, uv, _ = simulate_hand(12, 0.3, np.random.default_rng(40 + seed),
                                      joint_error=np.radians(0.1))
        fit = calibrate_board_camera(A, pts, uv, [f"{k:02d}" for k in range(12)],
                                     np.r_[LENS[:4], np.zeros(5)], "hand", holdout=0.0,
                                     sigma=0.3)
        ratios.append(np.linalg.norm(fit.X[:3, 3] - X_HAND[:3, 3]) / fit.expected_position)
    assert 1 / 1.5 < np.sqrt(np.mean(np.square(ratios))) < 1.5, ratios


def test_refusals() -> None:
    A, pts, uv, _ = simulate_hand(6, 0.3, np.random.default_rng(2))
    names = [f"{k}" for k in range(6)]
    with pytest.raises(KincalError, match="'k4' is not an intrinsic"):
        calibrate_board_camera(A, pts, uv, names, LENS, fit_lens=("k4",), holdout=0.0)
    with pytest.raises(KincalError, match="2 training images"):
        calibrate_board_camera(A[:2], pts[:2], uv[:2], names[:2], LENS, holdout=0.0)
    # a board always square to the camera at one distance: the focal lengths and that
    # distance scale together (u - cx = fx x / z), the fit names what it cannot separate
    pts0 = BOARD.corner_points(np.arange(24)) - [0.085, 0.12, 0.0]
    A = np.array([matrix_from_frame([0.05 * np.cos(k), 0.04 * np.sin(k), 0.5, 0.4 * k, 0, 0])
                  for k in range(5)])
    uv = [project_lens(pts0 @ T[:3, :3].T + T[:3, 3], LENS) for T in A]
    with pytest.raises(IdentifiabilityError, match="cannot tell apart .*(fx|fy|z)"):
        fit_board_camera(A, [pts0] * 5, uv, names[:5], LENS, np.eye(4), np.eye(4), "fixed")


def _write_pose(path, T: np.ndarray) -> None:
    from kincal.identify.hand_eye import quaternion

    v = [float(c) for c in np.r_[T[:3, 3], quaternion(T[:3, :3])[[1, 2, 3, 0]]]]
    path.write_text("".join(f"{k}: {c!r}\n" for k, c in
                            zip(("x", "y", "z", "qx", "qy", "qz", "qw"), v, strict=True)))


#: The fixed camera in the base and the board on the flange of
#: :func:`render_fixed_camera_set`.
FIXED_CAMERA = matrix_from_frame([0.0, 1.27, 0.28, -1.6, 0.1, -2.0])
FIXED_BOARD = matrix_from_frame([0.06, 0.12, 0.21, 0.5, 0.2, 0.3])


def render_fixed_camera_set(cv2, folder, rng: np.random.Generator, n: int = 9) -> np.ndarray:
    """A fixed camera (pinhole 900 px, 1280 x 720) photographs the ChArUco board on the
    flange: ``folder/board.yaml``, ``n`` images rendered by a perspective warp (blur,
    noise) in ``folder/img`` and the flange poses in ``folder/poses``; returns the
    camera's true pose in the base."""
    from test_camera_images import MARGIN, PX, _render

    (folder / "board.yaml").write_text("type: charuco\nsquares: [5, 7]\nsquare: 34 mm\n"
                                       "marker: 28 mm\ndictionary: DICT_6X6_250\n")
    Kt = np.array([[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])
    S = np.array([[PX / BOARD.square, 0, MARGIN - 0.5], [0, PX / BOARD.square, MARGIN - 0.5],
                  [0, 0, 1]])
    (folder / "img").mkdir()
    (folder / "poses").mkdir()
    k = 0
    while k < n:
        # the board's z axis away from the camera (printed face seen, not mirrored)
        seen = matrix_from_frame(np.r_[rng.uniform(-0.2, 0.05, 2), rng.uniform(0.5, 0.7),
                                       rng.uniform(-0.5, 0.5, 3)])
        x = BOARD.corner_points(np.arange(24)) @ seen[:3, :3].T + seen[:3, 3]
        uv = x[:, :2] / x[:, 2:] * 900 + [640, 360]
        if uv.min() < 40 or uv[:, 0].max() > 1240 or uv[:, 1].max() > 680:
            continue
        H = Kt @ np.column_stack([seen[:3, 0], seen[:3, 1], seen[:3, 3]]) @ np.linalg.inv(S)
        cv2.imwrite(str(folder / "img" / f"{k}.png"), _render(cv2, BOARD, H / H[2, 2], rng))
        _write_pose(folder / "poses" / f"{k}.yaml", FIXED_CAMERA @ seen @ inverse(FIXED_BOARD))
        k += 1
    return FIXED_CAMERA


def test_cli_eye_to_hand_from_rendered_images_and_pose_files(tmp_path, capsys) -> None:
    """A fixed camera (pinhole 900 px) photographs a ChArUco board on the flange: 9 images
    rendered by a perspective warp (blur, noise), flange poses as pose files; the command
    detects, starts from intrinsics 2 % off and finds the camera within its stated error."""
    cv2 = pytest.importorskip("cv2")
    import json

    from cli_helpers import run

    board_file = tmp_path / "board.yaml"
    camera = render_fixed_camera_set(cv2, tmp_path, np.random.default_rng(3))
    (tmp_path / "cam.yaml").write_text("camera_matrix: {rows: 3, cols: 3, data: [918, 0, 646,"
                                       " 0, 882, 355, 0, 0, 1]}\n")
    args = ["hand-eye", "--images", tmp_path / "img", "--board", board_file, "--poses",
            tmp_path / "poses", "--mount", "fixed", "--intrinsics", tmp_path / "cam.yaml"]
    code, out, err = run(capsys, *args, "--lens", "pinhole", "--json", tmp_path / "f.json")
    assert code == 0, err
    assert "camera in the base frame" in out and "expected error of the hand-eye" in out
    fit = json.loads((tmp_path / "f.json").read_text())
    X = np.array(fit["camera"]["matrix"])
    assert np.linalg.norm(X[:3, 3] - camera[:3, 3]) < 4 * fit["expected_error"]["position_m"]
    assert abs(fit["intrinsics"]["fx"] - 900) < 4 * fit["intrinsics_std"]["fx"] + 0.5
    assert fit["reprojection_rms_px"]["held_out"] < 1.0
    # refusals: one line, exit 2
    for extra, match in [(["panda"], "no ROBOT"), (["--lens", "fisheye"], "--lens fisheye"),
                         (["--free", "theta_offset*"], "--free")]:
        code, out, err = run(capsys, *args, *extra)
        assert code == 2 and err.count("\n") == 1 and match in err, err
    (tmp_path / "poses" / "4.yaml").unlink()
    code, out, err = run(capsys, *args)
    assert code == 2 and "no pose file for image 4.png" in err
