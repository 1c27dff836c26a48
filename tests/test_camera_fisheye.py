"""The fisheye lens (OpenCV's equidistant model) from raw pixels: known truth.

The projection against ``cv2.fisheye.projectPoints``, its analytic Jacobian against
central differences, the undistortion against the pinhole image of the same points; the
intrinsics files (ROS ``distortion_model: equidistant``, OpenCV's ``fisheye_model: 1``);
a hand camera with a known fisheye lens on a simulated Panda, from exact projections plus
noise, and from images rendered through that lens (every output pixel's ray traced back
to the printed board), detected and calibrated by ``kincal hand-eye --lens fisheye``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from kincal.errors import KincalError
from kincal.identify.hand_eye_lens import (
    _fisheye_jacobian,
    _moved,
    _residuals,
    calibrate_board_camera,
)
from kincal.identify.lens_fisheye import fisheye_jacobian, project_fisheye, undistort_fisheye
from kincal.measure.camera_board import Board
from kincal.robots.files import load_serial_robot
from kincal.spatial import inverse, log_so3, matrix_from_frame

BOARD = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
#: About a 640 x 480 fisheye of 160 deg across the diagonal.
FISH = np.array([250.0, 251.0, 322.0, 238.0, 0.06, -0.03, 0.012, -0.004])
W, H = 640, 480
Q0 = np.array([-0.22, -0.19, 0.0, -2.42, 0.28, 2.15, 0.31])
X_HAND = matrix_from_frame([0.040, -0.030, 0.065, 0.80, 0.01, -0.05])
BOARD_FROM_Q0 = matrix_from_frame([-0.085, -0.12, 0.24, 0.2, 0.1, -0.1])


def _rot(A: np.ndarray, B: np.ndarray) -> float:
    return float(np.linalg.norm(log_so3(A[:3, :3] @ B[:3, :3].T)))


def test_projection_is_opencvs_and_jacobian_is_the_derivative() -> None:
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(0)
    # up to 70 deg off the axis
    x = np.column_stack([rng.uniform(-1.4, 1.4, (60, 2)), rng.uniform(0.5, 1.0, 60)])
    K = np.array([[FISH[0], 0, FISH[2]], [0, FISH[1], FISH[3]], [0, 0, 1]])
    ref = cv2.fisheye.projectPoints(x.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                                    FISH[4:])[0].reshape(-1, 2)
    assert np.abs(project_fisheye(x, FISH) - ref).max() < 1e-9
    pin = x[:, :2] / x[:, 2:] * FISH[:2] + FISH[2:4]
    assert np.abs(undistort_fisheye(ref, FISH) - pin).max() < 1e-8
    jx, jl = fisheye_jacobian(x, FISH)
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        fd = (project_fisheye(x + d, FISH) - project_fisheye(x - d, FISH)) / 2e-6
        assert np.abs(fd - jx[:, :, k]).max() < 1e-6 * np.abs(fd).max(), k
    for k in range(8):
        d = np.zeros(8)
        d[k] = 1e-4 if k < 4 else 1e-7
        fd = (project_fisheye(x, FISH + d) - project_fisheye(x, FISH - d)) / (2 * d[k])
        assert np.abs(fd - jl[:, :, k]).max() < 1e-6 * np.abs(fd).max(), k
    # on the optical axis: the limit s -> 1 / x3
    assert np.allclose(project_fisheye(np.array([[0.0, 0.0, 2.0]]), FISH), [FISH[2:4]])


def test_the_fits_jacobian_is_the_residuals_derivative() -> None:
    """The analytic Jacobian of the joint fit (hand-eye, board pose, 8 intrinsics) against
    central differences of the residuals under the fit's own pose update."""
    rng = np.random.default_rng(1)
    X, Z = matrix_from_frame([0.04, -0.03, 0.06, 0.8, 0.01, -0.05]), BOARD_FROM_Q0
    C = [matrix_from_frame(rng.uniform(-0.2, 0.2, 6)) for _ in range(3)]
    P = [BOARD.corner_points(np.arange(24))] * 3
    uv = [np.zeros((24, 2))] * 3
    J = _fisheye_jacobian(C, P, X, Z, FISH, range(8))
    for k in range(20):
        d = np.zeros(20)
        d[k] = 1e-4 if 12 <= k < 16 else 1e-7

        def r(sign: float, d: np.ndarray = d) -> np.ndarray:
            return _residuals(C, P, uv, _moved(X, sign * d[:6]), _moved(Z, sign * d[6:12]),
                              FISH + sign * d[12:], "fisheye")

        fd = (r(1.0) - r(-1.0)) / (2 * d[k])
        assert np.abs(fd - J[:, k]).max() < 1e-5 * np.abs(fd).max(), k


def test_intrinsics_files_equidistant(tmp_path: Path) -> None:
    from kincal.measure.camera_images import read_intrinsics

    ros = tmp_path / "camera_info.yaml"
    ros.write_text("image_width: 640\nimage_height: 480\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
                   "  data: [250, 0, 322, 0, 251, 238, 0, 0, 1]\n"
                   "distortion_model: equidistant\ndistortion_coefficients:\n  rows: 1\n"
                   "  cols: 4\n  data: [0.06, -0.03, 0.012, -0.004]\n")
    i = read_intrinsics(ros)
    assert i.model == "equidistant" and i.dist == (0.06, -0.03, 0.012, -0.004)
    assert i.pinhole == (250.0, 251.0, 322.0, 238.0)
    ros.write_text(ros.read_text().replace("equidistant", "kannala_brandt_42"))
    with pytest.raises(KincalError, match="distortion_model: 'kannala_brandt_42' is not") as e:
        read_intrinsics(ros)
    assert str(ros) in str(e.value) and "\n" not in str(e.value)
    ros.write_text(ros.read_text().replace("kannala_brandt_42", "equidistant")
                   .replace("-0.004]", "-0.004, 0.0]"))
    with pytest.raises(KincalError, match="4 coefficients"):
        read_intrinsics(ros)
    cv2 = pytest.importorskip("cv2")
    ocv = tmp_path / "opencv.yaml"
    fs = cv2.FileStorage(str(ocv), cv2.FILE_STORAGE_WRITE)
    fs.write("fisheye_model", 1)
    fs.write("camera_matrix", np.array([[250.0, 0, 322], [0, 251.0, 238], [0, 0, 1]]))
    fs.write("distortion_coefficients", FISH[4:].reshape(4, 1))
    fs.release()
    i = read_intrinsics(ocv)
    assert i.model == "equidistant" and np.allclose(i.dist, FISH[4:])
    # the measurement file's pinhole pixels: the fisheye's distortion removed
    from kincal.measure.camera_images import undistort

    x = np.column_stack([np.linspace(-1.2, 1.2, 9), np.linspace(0.8, -0.8, 9), np.ones(9)])
    pin = x[:, :2] / x[:, 2:] * FISH[:2] + FISH[2:4]
    assert np.abs(undistort(project_fisheye(x, FISH), i) - pin).max() < 1e-6


def test_lens_option_follows_the_start_intrinsics() -> None:
    from kincal.identify.hand_eye_lens import FISHEYE, LENS, lens_start
    from kincal.measure.camera_images import Intrinsics

    fish = Intrinsics(250.0, 251.0, 322.0, 238.0, (0.06, -0.03, 0.012, -0.004), "f.yaml",
                      "equidistant")
    model, lens0, fitted = lens_start(fish, "all")
    assert model == "fisheye" and fitted == FISHEYE and np.array_equal(lens0, FISH)
    assert lens_start(fish, "pinhole")[2] == FISHEYE[:4] and lens_start(fish, "none")[2] == ()
    radtan = Intrinsics(900.0, 901.0, 640.0, 360.0, (0.1, -0.2, 0.0, 0.0), "cam.yaml")
    model, lens0, fitted = lens_start(radtan, "all")
    assert model == "radtan" and fitted == LENS and lens0[-1] == 0.0 and len(lens0) == 9
    with pytest.raises(KincalError, match="--lens fisheye: the start intrinsics .cam.yaml. "
                       "are a plumb_bob lens"):
        lens_start(radtan, "fisheye")


def _corners_in_view(B: np.ndarray, pts: np.ndarray, margin: float) -> np.ndarray | None:
    x = pts @ B[:3, :3].T + B[:3, 3]
    if np.any(x[:, 2] < 0.05):
        return None
    uv = project_fisheye(x, FISH)
    inside = ((uv[:, 0] > margin) & (uv[:, 0] < W - margin) & (uv[:, 1] > margin)
              & (uv[:, 1] < H - margin))
    return uv if inside.all() else None


def _poses(n: int, rng: np.random.Generator, margin: float = 8.0
           ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """Joint values, board-in-camera poses and exact corner pixels of ``n`` views."""
    robot = load_serial_robot("panda")
    pts = BOARD.corner_points(np.arange(BOARD.num_corners))
    Z = robot.fk(Q0) @ X_HAND @ BOARD_FROM_Q0
    q, B, uv = [], [], []
    while len(q) < n:
        qi = Q0 + rng.uniform(-0.45, 0.45, 7)
        Bi = inverse(X_HAND) @ inverse(robot.fk(qi)) @ Z
        p = _corners_in_view(Bi, pts, margin)
        if p is not None:
            q.append(qi)
            B.append(Bi)
            uv.append(p)
    return np.array(q), np.array(B), uv


def test_fisheye_and_hand_eye_recovered_together() -> None:
    """12 views, 0.3 px: every fisheye intrinsic within 4 standard errors from a start
    3 % off with k = 0; the hand-eye within 4 expected errors; held-out at the noise."""
    rng = np.random.default_rng(7)
    q, _, uv = _poses(12, rng)
    uv = [p + rng.normal(0.0, 0.3, p.shape) for p in uv]
    robot = load_serial_robot("panda")
    pts = [BOARD.corner_points(np.arange(24))] * 12
    start = np.r_[FISH[:4] * [1.03, 0.97, 1.0, 1.0] + [0, 0, 5, -4], np.zeros(4)]
    fit = calibrate_board_camera(robot.fk(q), pts, uv, [f"{k:02d}" for k in range(12)], start,
                                 "hand", 0.25, sigma=0.3, model="fisheye")
    assert fit.lens_names[4:] == ("k1", "k2", "k3", "k4")
    assert np.all(np.abs(fit.lens - FISH) < 4 * fit.lens_std), (fit.lens - FISH) / fit.lens_std
    assert np.linalg.norm(fit.X[:3, 3] - X_HAND[:3, 3]) < 4 * fit.expected_position
    assert _rot(fit.X, X_HAND) < 4 * fit.expected_rotation
    assert fit.held_rms_px < 0.3 * np.sqrt(2) * 1.5
    with pytest.raises(KincalError, match="'p1' is not an intrinsic of the fisheye lens"):
        calibrate_board_camera(robot.fk(q), pts, uv, [f"{k}" for k in range(12)], start,
                               fit_lens=("p1",), model="fisheye")


def test_expected_error_is_honest_with_the_fisheye_fitted() -> None:
    """Monte Carlo over 8 sets of 12 views (0.3 px, and 0.1 deg of joint error per joint
    and view that nothing models): the true hand-eye error over the expected error, RMS
    in 1/1.5 .. 1.5."""
    robot = load_serial_robot("panda")
    pts = [BOARD.corner_points(np.arange(24))] * 12
    ratios = []
    for seed in range(8):
        rng = np.random.default_rng(60 + seed)
        q, _, uv = _poses(12, rng)
        true = q + rng.normal(0.0, np.radians(0.1), q.shape)   # where the arm really was
        Z = robot.fk(Q0) @ X_HAND @ BOARD_FROM_Q0
        pts0 = BOARD.corner_points(np.arange(24))
        uv = [project_fisheye(pts0 @ B[:3, :3].T + B[:3, 3], FISH) + rng.normal(0, 0.3, (24, 2))
              for B in inverse(X_HAND) @ inverse(robot.fk(true)) @ Z]
        fit = calibrate_board_camera(robot.fk(q), pts, uv, [f"{k:02d}" for k in range(12)],
                                     np.r_[FISH[:4], np.zeros(4)], "hand", 0.0, sigma=0.3,
                                     model="fisheye")
        ratios.append(np.linalg.norm(fit.X[:3, 3] - X_HAND[:3, 3]) / fit.expected_position)
    assert 1 / 1.5 < np.sqrt(np.mean(np.square(ratios))) < 1.5, ratios


def _render(cv2, B: np.ndarray, rays: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The printed board (100 px per square, 20 px white margin) seen through the fisheye:
    each output pixel's ray (``rays``, (H W, 3), on z = 1) meets the board plane at
    ``t ray`` with ``t = n . T / n . ray``; its board coordinates pick the printed pixel
    (bilinear, the print blurred by 1 px against aliasing), then blur (sigma 0.7 px) and
    noise (2 grey levels)."""
    px, margin = 100, 20
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    flat = np.pad(cv2.aruco.CharucoBoard((5, 7), BOARD.square, BOARD.marker, d)
                  .generateImage((5 * px, 7 * px)), margin, constant_values=255)
    flat = cv2.GaussianBlur(flat, (0, 0), 1.0)      # no aliasing where squares shrink
    n, T = B[:3, 2], B[:3, 3]
    t = (n @ T) / (rays @ n)
    p = (t[:, None] * rays - T) @ B[:3, :3]
    mx = (p[:, 0] / BOARD.square * px + margin - 0.5).reshape(H, W).astype(np.float32)
    my = (p[:, 1] / BOARD.square * px + margin - 0.5).reshape(H, W).astype(np.float32)
    bad = ~np.isfinite(mx) | (t.reshape(H, W) <= 0)
    mx[bad], my[bad] = -10.0, -10.0
    img = cv2.remap(flat, mx, my, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=255)
    img = cv2.GaussianBlur(img, (0, 0), 0.7).astype(float) + rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_cli_fisheye_from_rendered_images(tmp_path: Path, capsys) -> None:
    """10 images rendered through the fisheye (no intrinsics given: cv2.fisheye.calibrate
    starts the fit; the views where the detector misses most corners near the image's
    rim are dropped with the reason): the lens and the hand-eye within their stated uncertainty."""
    cv2 = pytest.importorskip("cv2")
    from cli_helpers import run

    rng = np.random.default_rng(11)
    q, B, _ = _poses(10, rng, margin=25.0)
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    pin = undistort_fisheye(np.column_stack([u.ravel(), v.ravel()]), FISH)
    rays = np.column_stack([(pin - FISH[2:4]) / FISH[:2], np.ones(len(pin))])
    (tmp_path / "img").mkdir()
    rows = ["image," + ",".join(f"q{k + 1}_rad" for k in range(7))]
    for k in range(10):
        cv2.imwrite(str(tmp_path / "img" / f"{k:02d}.png"), _render(cv2, B[k], rays, rng))
        rows.append(f"{k:02d}.png," + ",".join(repr(float(v)) for v in q[k]))
    (tmp_path / "joints.csv").write_text("\n".join(rows) + "\n")
    board = tmp_path / "board.yaml"
    board.write_text("type: charuco\nsquares: [5, 7]\nsquare: 34 mm\nmarker: 28 mm\n"
                     "dictionary: DICT_6X6_250\n")
    code, out, err = run(capsys, "hand-eye", "panda", "--images", tmp_path / "img", "--board",
                         board, "--joints", tmp_path / "joints.csv", "--lens", "fisheye",
                         "--json", tmp_path / "f.json", "--camera-info", tmp_path / "ci.yaml")
    assert code == 0, err
    assert "cv2.fisheye.calibrate" in out and "intrinsics (fisheye, equidistant)" in out
    found = re.search(r"(\d+) images with the board, (\d+) dropped", out)
    assert found and int(found[1]) >= 7 and int(found[1]) + int(found[2]) == 10, out
    assert int(found[2]) == out.count("too few corners") + out.count("board not found")
    fit = json.loads((tmp_path / "f.json").read_text())
    assert fit["lens_model"] == "fisheye"
    for k, name in enumerate(("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")):
        assert abs(fit["intrinsics"][name] - FISH[k]) < 4 * fit["intrinsics_std"][name], name
    X = np.array(fit["camera"]["matrix"])
    assert np.linalg.norm(X[:3, 3] - X_HAND[:3, 3]) < 4 * fit["expected_error"]["position_m"]
    assert _rot(X, X_HAND) < 4 * fit["expected_error"]["rotation_rad"]
    assert fit["reprojection_rms_px"]["held_out"] < 1.0
    # the camera_info says equidistant and reads back as the fitted lens
    from kincal.measure.camera_images import read_intrinsics

    info = read_intrinsics(tmp_path / "ci.yaml")
    assert info.model == "equidistant"
    assert (info.fx, info.fy, info.cx, info.cy) == tuple(
        fit["intrinsics"][k] for k in ("fx", "fy", "cx", "cy"))
    assert info.dist == tuple(fit["intrinsics"][k] for k in ("k1", "k2", "k3", "k4"))

