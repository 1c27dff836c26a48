"""Board images in: detection on rendered images (known corner pixels), the real Franka set,
the board file, and the one-line refusals (no OpenCV, bad board file, rotations)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

from kincal.errors import KincalError
from kincal.measure.camera_board import Board, board_pose, read_board

ROOT = Path(__file__).resolve().parents[1]
FRANKA = ROOT.parent / "shared" / "data" / "camera" / "franka_eye_in_hand"
PX = 100                   # rendered board: pixels per square (OpenCV 5.0 draws 100 exactly)
MARGIN = 20


def _render(cv2, board: Board, H: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The board drawn flat, warped by the homography H into a 1280 x 720 image, blurred
    (Gaussian, sigma 0.8 px) and with pixel noise (sigma 2 grey levels)."""
    size = (board.columns * PX + 2 * MARGIN, board.rows * PX + 2 * MARGIN)
    if board.kind == "charuco":
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary))
        drawn = cv2.aruco.CharucoBoard((board.columns, board.rows), board.square,
                                       board.marker, d).generateImage((board.columns * PX,
                                                                       board.rows * PX))
        flat = np.pad(drawn, MARGIN, constant_values=255)   # (OpenCV 5.0's margin fails)
    else:
        flat = np.full(size[::-1], 255, np.uint8)
        for r in range(board.rows):
            for c in range(board.columns):
                if (r + c) % 2 == 0:
                    flat[MARGIN + r * PX:MARGIN + (r + 1) * PX,
                         MARGIN + c * PX:MARGIN + (c + 1) * PX] = 0
    img = cv2.warpPerspective(flat, H, (1280, 720), borderValue=255)
    img = cv2.GaussianBlur(img, (0, 0), 0.8).astype(float) + rng.normal(0, 2.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _true_pixels(board: Board, ids: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Where corner ``ids`` land: board metres -> flat-image pixels (pixel centres at
    integers: a square edge lies half a pixel before its first pixel) -> H."""
    P = board.corner_points(ids)[:, :2] / board.square * PX + MARGIN - 0.5
    h = np.column_stack([P, np.ones(len(P))]) @ H.T
    return h[:, :2] / h[:, 2:]


H_VIEW = np.array([[1.05, 0.18, 330.0], [-0.12, 0.95, 90.0], [1.2e-4, 2.0e-4, 1.0]]) @ np.diag(
    [0.6, 0.6, 1.0])


@pytest.mark.parametrize("kind", ["charuco", "chessboard"])
def test_rendered_board_corners_are_found_to_a_fraction_of_a_pixel(kind: str) -> None:
    cv2 = pytest.importorskip("cv2")
    from kincal.measure.camera_images import detect_board

    board = Board(kind, 5, 7, 0.034, 0.028 if kind == "charuco" else 0.0,
                  "DICT_6X6_250" if kind == "charuco" else "")
    img = _render(cv2, board, H_VIEW, np.random.default_rng(0))
    ids, uv = detect_board(cv2, img, board)
    assert len(ids) == board.num_corners
    err = np.linalg.norm(uv - _true_pixels(board, ids, H_VIEW), axis=1)
    if kind == "chessboard" and err.mean() > 5:      # found from the other end: 180 deg
        err = np.linalg.norm(uv - _true_pixels(board, ids[::-1], H_VIEW), axis=1)
    # measured with OpenCV 5.0: chessboard 0.11 px max, ChArUco (markers 82 % of the
    # square, close to the corners) 0.3 px max; the bounds leave room for other versions
    assert err.mean() < 0.2 and err.max() < 0.5, (err.mean(), err.max())


def test_charuco_corner_positions_are_opencvs() -> None:
    cv2 = pytest.importorskip("cv2")
    board = Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    ref = cv2.aruco.CharucoBoard((5, 7), 0.034, 0.028, d).getChessboardCorners()
    assert np.abs(board.corner_points(np.arange(24)) - ref).max() < 1e-7   # float32


def test_board_file_forms_and_errors(tmp_path: Path) -> None:
    f = tmp_path / "b.yaml"
    f.write_text("type: charuco\nsquares: [5, 7]\nsquare: 3.4 cm\nmarker: 28 mm\n"
                 "dictionary: DICT_6X6_250\n")
    b = read_board(f)
    assert (b.kind, b.columns, b.rows, b.dictionary) == ("charuco", 5, 7, "DICT_6X6_250")
    assert b.square == pytest.approx(0.034, rel=1e-12) and b.marker == pytest.approx(0.028)
    f.write_text("board_size: [5, 7]\nsquare_length: 0.034\nmarker_length: 0.028\n")
    assert read_board(f) == Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250")
    for text, match in [("type: charuco\nsquares: [5, 7]\nsquare: 34 furlong\nmarker: 2 mm\n",
                         "square: '34 furlong' is not a length"),
                        ("type: ellipses\nsquares: [5, 7]\n", "type: 'ellipses'"),
                        ("type: chessboard\nsquares: [5]\nsquare: 3 cm\n", "squares: two"),
                        ("type: charuco\nsquares: [5, 7]\nsquare: 3 cm\nmarker: 4 cm\n",
                         "smaller than the square")]:
        f.write_text(text)
        with pytest.raises(KincalError, match=match):
            read_board(f)


def test_without_opencv_the_command_says_what_to_install(tmp_path: Path, capsys,
                                                         monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "cv2", None)       # import cv2 -> ImportError
    (tmp_path / "b.yaml").write_text("type: chessboard\nsquares: [5, 7]\nsquare: 3 cm\n")
    code, out, err = run(capsys, "import", "images", str(tmp_path), "--board",
                         tmp_path / "b.yaml", "-o", tmp_path / "d.csv")
    assert code == 2 and err.strip().count("\n") == 0 and "kincal[camera]" in err
    assert not (tmp_path / "d.csv").exists()


def test_dropped_images_are_listed_with_the_reason(tmp_path: Path, capsys) -> None:
    cv2 = pytest.importorskip("cv2")
    board = Board("chessboard", 5, 7, 0.03)
    img = _render(cv2, board, H_VIEW, np.random.default_rng(1))
    cv2.imwrite(str(tmp_path / "a.png"), img)
    cv2.imwrite(str(tmp_path / "b.png"), np.full((720, 1280), 128, np.uint8))
    (tmp_path / "board.yaml").write_text("type: chessboard\nsquares: [5, 7]\nsquare: 30 mm\n")
    (tmp_path / "joints.csv").write_text("image,q1_deg,q2_deg\na.png,10,20\nb.png,0,0\n")
    (tmp_path / "cam.yaml").write_text("camera_matrix: {rows: 3, cols: 3, data: [900, 0, 640,"
                                       " 0, 900, 360, 0, 0, 1]}\n")
    code, out, err = run(capsys, "import", "images", tmp_path, "--board", tmp_path /
                         "board.yaml", "--joints", tmp_path / "joints.csv", "--intrinsics",
                         tmp_path / "cam.yaml", "-o", tmp_path / "d.csv")
    assert code == 0, err
    assert "1 images with the board, 24 corners; 1 dropped" in out
    assert "b.png: board not found" in out
    text = (tmp_path / "d.csv").read_text()
    assert "mount=hand" in text and ",a.png," in text and "b.png," not in text.split("\n", 5)[5]


@pytest.mark.skipif(not FRANKA.is_dir(), reason="the real camera data are not here")
def test_real_franka_set_import_and_hand_eye(tmp_path: Path, capsys) -> None:
    pytest.importorskip("cv2")
    from kincal.measure.camera_images import detect_images, undistort

    board = read_board(FRANKA / "config" / "calibration_board_parameters.yaml")
    images = detect_images(FRANKA / "session_1", board)
    assert len(images.detections) == 12 and not images.dropped
    assert images.intrinsics is not None
    # our board pose against the capture tool's own (its detection, its solvePnP)
    for d in images.detections:
        T, rms = board_pose(board.corner_points(d.ids), undistort(d.uv, images.intrinsics),
                            images.intrinsics.pinhole)
        ref = json.loads((FRANKA / "session_1" / d.image / "data.json").read_text())
        assert np.linalg.norm(T[:3, 3] - np.ravel(ref["T_cam_target_tvec"])) < 2e-3
        assert rms < 1.0
    data = tmp_path / "franka.csv"
    code, out, err = run(capsys, "import", "images", FRANKA / "session_1", "--board",
                         FRANKA / "config" / "calibration_board_parameters.yaml", "--robot",
                         "panda", "-o", data)
    assert code == 0, err
    code, out, err = run(capsys, "hand-eye", "panda", "--data", data, "--free",
                         "theta_offset*", "--json", tmp_path / "fit.json")
    assert code == 0, err
    fit = json.loads((tmp_path / "fit.json").read_text())
    assert fit["held_out"] == ["pose_02", "pose_06", "pose_10"]
    # held-out pixels: within a few times the corner noise the training fit shows
    rms = fit["reprojection_rms_px"]
    assert rms["held_out"] < 3 * rms["training"]


def test_intrinsics_files_ros_and_opencv(tmp_path: Path) -> None:
    from kincal.measure.camera_images import read_intrinsics

    ros = tmp_path / "camera_info.yaml"
    ros.write_text("image_width: 1280\nimage_height: 720\ncamera_matrix:\n  rows: 3\n  cols: 3\n"
                   "  data: [633.9, 0, 642.0, 0, 633.4, 359.0, 0, 0, 1]\n"
                   "distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n"
                   "  cols: 5\n  data: [-0.06, 0.07, -0.0002, 0.0005, -0.02]\n")
    i = read_intrinsics(ros)
    assert i.pinhole == (633.9, 633.4, 642.0, 359.0) and i.dist[0] == -0.06
    ros.write_text("camera_matrix: {data: [0, 0, 642, 0, 633, 359, 0, 0, 1]}\n")
    with pytest.raises(KincalError, match="fx, fy > 0"):
        read_intrinsics(ros)
    cv2 = pytest.importorskip("cv2")
    ocv = tmp_path / "opencv.yaml"
    fs = cv2.FileStorage(str(ocv), cv2.FILE_STORAGE_WRITE)
    fs.write("camera_matrix", np.array([[900.0, 0, 640], [0, 901.0, 360], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[0.1, -0.2, 0.0, 0.0, 0.05]]))
    fs.release()
    i = read_intrinsics(ocv)
    assert i.pinhole == (900.0, 901.0, 640.0, 360.0) and i.dist == (0.1, -0.2, 0.0, 0.0, 0.05)


def test_blurred_and_oblique_boards_are_dropped_with_the_reason(tmp_path: Path,
                                                                capsys) -> None:
    """Rendered chessboards: one sharp, one with 14 px of horizontal motion blur (still
    detected, all 24 corners), one tilted 66 deg from the viewing ray (detected too); the
    two are dropped, each with its measured figure and the threshold, the sharp one kept.
    The tilt from the true corner pixels is the rendered one (to 0.01 deg)."""
    cv2 = pytest.importorskip("cv2")
    from kincal.measure.camera_images import (
        Detection,
        Intrinsics,
        board_sharpness,
        tilt_deg,
    )
    from kincal.spatial import matrix_from_frame

    board = Board("chessboard", 5, 7, 0.03)
    sharp = _render(cv2, board, H_VIEW, np.random.default_rng(1))
    k = np.zeros((14, 14))
    k[7, :] = 1 / 14
    blurred = cv2.filter2D(sharp, -1, k)
    K = np.array([[900.0, 0, 640], [0, 900, 360], [0, 0, 1]])
    S = np.array([[PX / board.square, 0, MARGIN - 0.5], [0, PX / board.square, MARGIN - 0.5],
                  [0, 0, 1]])
    R = matrix_from_frame([0, 0, 0, 0.3, 0.0, np.radians(66)])[:3, :3]
    t = np.array([0, 0, 0.45]) - R @ [board.columns * board.square / 2,
                                      board.rows * board.square / 2, 0]
    H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ np.linalg.inv(S)
    oblique = _render(cv2, board, H / H[2, 2], np.random.default_rng(2))
    ids = np.arange(24)
    truth = Detection("o", ids, _true_pixels(board, ids, H / H[2, 2]), np.zeros(1))
    assert abs(tilt_deg(board, truth, Intrinsics(900, 900, 640, 360)) - 66) < 0.01
    uv = _true_pixels(board, ids, H_VIEW)
    assert board_sharpness(cv2, sharp, uv) > 3 * board_sharpness(cv2, blurred, uv)
    for name, img in [("a.png", sharp), ("b.png", blurred), ("c.png", oblique)]:
        cv2.imwrite(str(tmp_path / name), img)
    (tmp_path / "board.yaml").write_text("type: chessboard\nsquares: [5, 7]\nsquare: 30 mm\n")
    (tmp_path / "joints.csv").write_text("image,q1_deg\na.png,1\nb.png,2\nc.png,3\n")
    (tmp_path / "cam.yaml").write_text("camera_matrix: {rows: 3, cols: 3, data: [900, 0, 640,"
                                       " 0, 900, 360, 0, 0, 1]}\n")
    args = ["import", "images", tmp_path, "--board", tmp_path / "board.yaml", "--joints",
            tmp_path / "joints.csv", "--intrinsics", tmp_path / "cam.yaml", "-o",
            tmp_path / "d.csv"]
    code, out, err = run(capsys, *args)
    assert code == 0, err
    text = " ".join(out.split())
    assert "1 images with the board, 24 corners; 2 dropped" in text
    assert "b.png: motion blur (sharpness 0.1" in text and "< 0.15 px^-3" in text
    assert "c.png: board too oblique (66 deg between its normal and the viewing ray > 60" \
        in text
    # the thresholds are options (the blurred image alone: its detection is fast)
    (tmp_path / "b").mkdir()
    cv2.imwrite(str(tmp_path / "b" / "b.png"), blurred)
    args[2] = tmp_path / "b"
    code, out, err = run(capsys, *args, "--min-sharpness", "0.05")
    assert code == 0 and "1 images with the board, 24 corners; 0 dropped" in out, err


@pytest.mark.parametrize("kind,dictionary", [("aruco_grid", "DICT_6X6_250"),
                                             ("apriltag_grid", "DICT_APRILTAG_36H11")])
def test_marker_grids_rendered_corners_and_opencvs_layout(tmp_path: Path, kind: str,
                                                          dictionary: str) -> None:
    """ArUco and AprilTag grids (4 x 5 markers, 80 px markers on a 100 px pitch) drawn
    marker by marker, warped, blurred and noisy: every marker corner found within a
    fraction of a pixel of where the warp put it; the board file read; the corner layout
    is OpenCV's GridBoard's."""
    cv2 = pytest.importorskip("cv2")
    from kincal.measure.camera_images import aruco_dictionary, detect_board

    f = tmp_path / "grid.yaml"
    f.write_text(f"type: {kind}\nmarkers: [4, 5]\nmarker: 32 mm\nseparation: 8 mm\n"
                 + ("" if kind == "apriltag_grid" else f"dictionary: {dictionary}\n"))
    board = read_board(f)
    assert (board.kind, board.columns, board.rows, board.dictionary) == (
        "aruco_grid", 4, 5, dictionary)
    assert board.square == pytest.approx(0.040) and board.marker == pytest.approx(0.032)
    d = aruco_dictionary(cv2, dictionary)
    ref = np.array(cv2.aruco.GridBoard((4, 5), 0.032, 0.008, d).getObjPoints()).reshape(-1, 3)
    assert np.abs(board.corner_points(np.arange(80)) - ref).max() < 1e-7
    flat = np.full((5 * PX + 2 * MARGIN, 4 * PX + 2 * MARGIN), 255, np.uint8)
    for m in range(20):
        x0, y0 = MARGIN + (m % 4) * PX, MARGIN + (m // 4) * PX
        flat[y0:y0 + 80, x0:x0 + 80] = cv2.aruco.generateImageMarker(d, m, 80)
    img = cv2.warpPerspective(flat, H_VIEW, (1280, 720), borderValue=255)
    rng = np.random.default_rng(4)
    img = cv2.GaussianBlur(img, (0, 0), 0.8).astype(float) + rng.normal(0, 2.0, img.shape)
    img = np.clip(img, 0, 255).astype(np.uint8)
    ids, uv = detect_board(cv2, img, board)
    assert len(ids) == 80 and np.array_equal(ids, np.arange(80))
    err = np.linalg.norm(uv - _true_pixels(board, ids, H_VIEW), axis=1)
    # measured (ArUco): 0.05 px mean, 0.11 max with the edge-line refinement; OpenCV's
    # own CORNER_REFINE_SUBPIX alone: 0.39 mean, 0.63 max (pulled into the marker)
    assert err.mean() < 0.1 and err.max() < 0.25, (err.mean(), err.max())


@pytest.mark.skipif(not FRANKA.is_dir(), reason="the real camera data are not here")
def test_real_franka_set_lens_in_the_fit(tmp_path: Path, capsys) -> None:
    """From the images, intrinsics and distortion fitted with the hand-eye and the joint
    offsets: the held-out images are predicted better than with the factory intrinsics
    (0.64 px against 0.96 px when recorded), and the robot written is the camera's."""
    pytest.importorskip("cv2")
    from kincal.robots.files import load_serial_robot

    board = FRANKA / "config" / "calibration_board_parameters.yaml"
    code, out, err = run(capsys, "hand-eye", "panda", "--images", FRANKA / "session_1",
                         "--board", board, "--free", "theta_offset*", "-o",
                         tmp_path / "cam.yaml", "--json", tmp_path / "lens.json")
    assert code == 0, err
    code, out, err = run(capsys, "import", "images", FRANKA / "session_1", "--board", board,
                         "--robot", "panda", "-o", tmp_path / "franka.csv")
    assert code == 0, err
    code, out, err = run(capsys, "hand-eye", "panda", "--data", tmp_path / "franka.csv",
                         "--free", "theta_offset*", "--json", tmp_path / "pin.json")
    assert code == 0, err
    lens = json.loads((tmp_path / "lens.json").read_text())
    pin = json.loads((tmp_path / "pin.json").read_text())
    assert lens["held_out"] == pin["held_out"] == ["pose_02", "pose_06", "pose_10"]
    assert lens["reprojection_rms_px"]["held_out"] < pin["reprojection_rms_px"]["held_out"]
    assert set(lens["robot_parameters"]) == {f"theta_offset[{k}]" for k in range(2, 7)}
    cam = load_serial_robot(str(tmp_path / "cam.yaml"))
    X = np.array(lens["camera"]["matrix"])
    flange = load_serial_robot("panda").frame_parameters("tool")
    from kincal.spatial import matrix_from_frame

    assert np.allclose(matrix_from_frame(cam.frame_parameters("tool")),
                       matrix_from_frame(flange) @ X, atol=1e-9)
