"""Printed boards from pixels: ``kincal board`` writes each kind, the page is warped by a
known camera (perspective, blur, noise) and detected; the corner ids and sub-pixel
positions are checked against the projection of the board file's object points. Also
the page sizes (PNG pixels, PDF MediaBox), the board file's round trip, circle grids in
``kincal import images`` and the one-line refusals."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run

from kincal.errors import KincalError
from kincal.measure.camera_board import Board, board_yaml, read_board

#: The camera: 640 x 480 pixels, f = 600 px; the board 0.55 m away, tilted.
K = np.array([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]])
SIZE = (640, 480)
DPI = 60
BLUR, NOISE = 0.7, 2.0          # Gaussian blur sigma [px] and grey-level noise sigma


def _rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    from kincal.spatial import matrix_from_frame

    return matrix_from_frame([0, 0, 0, *np.radians([rx, ry, rz])])[:3, :3]


def _view(board: Board, tilt: tuple[float, float, float], depth: float = 0.55):
    """Camera-from-board rotation and translation: the pattern's centre on the optical
    axis at ``depth`` [m]."""
    R = _rotation(*tilt)
    x0, y0, x1, y1 = board.extent()
    t = np.array([0.0, 0.0, depth]) - R @ [(x0 + x1) / 2, (y0 + y1) / 2, 0.0]
    return R, t


def _project(P: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    x = P @ R.T + t
    uv = x @ K.T
    return uv[:, :2] / uv[:, 2:]


def _photograph(cv2, page_png: Path, board: Board, R, t, rng) -> np.ndarray:
    """The printed page seen by the camera: page pixel (j, i) (centre at whole numbers)
    is the board point ``((j + 1/2) p - o, (i + 1/2) p - o)``, ``p`` the pixel, ``o`` the
    10 mm margin (plus a circle's radius on a circle grid, whose origin is the first
    centre); H = K [r1 r2 t] S; then blur and noise."""
    o = 0.010 + (board.marker / 2 if "circles" in board.kind else 0.0)
    p = 0.0254 / DPI
    S = np.array([[p, 0, 0.5 * p - o], [0, p, 0.5 * p - o], [0, 0, 1]])
    H = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ S
    flat = cv2.imread(str(page_png), cv2.IMREAD_GRAYSCALE)
    img = cv2.warpPerspective(flat, H / H[2, 2], SIZE, flags=cv2.INTER_LINEAR,
                              borderValue=255)
    img = cv2.GaussianBlur(img, (0, 0), BLUR).astype(float) + rng.normal(0, NOISE, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


#: (kind, extra options, tilt about x, y, z [deg], whether the board's 180-degree turn
#: is the same pattern, max corner error [px] allowed).
CASES = [
    ("charuco", ["--columns", "5", "--rows", "7"], (20, -15, 8), False, 0.2),
    ("chessboard", ["--columns", "6", "--rows", "8", "--square", "30mm"], (20, -15, 8), True, 0.2),
    ("aruco-grid", ["--columns", "3", "--rows", "4", "--marker", "45mm"], (20, -15, 8),
     False, 0.2),
    ("apriltag-grid", ["--columns", "3", "--rows", "4", "--marker", "45mm"], (-20, 15, -8),
     False, 0.2),
    ("circles", ["--columns", "5", "--rows", "6", "--spacing", "30mm", "--diameter",
                 "15mm"], (20, -15, 8), True, 0.2),
    ("asymmetric-circles", [], (20, -15, 8), False, 0.2),
]


@pytest.mark.parametrize("kind,opts,tilt,turns,tol", CASES, ids=[c[0] for c in CASES])
def test_printed_board_is_detected_where_the_camera_sees_it(tmp_path: Path, capsys, kind,
                                                            opts, tilt, turns, tol) -> None:
    """Every corner (circle centre) found, with its id, within a fraction of a pixel of
    the projection of its object point (blur 0.7 px, noise 2 grey levels; the bound
    leaves room for other OpenCV versions).  The asymmetric grid is seen upside down
    (turned 170 deg): its ids still follow the board, not the image."""
    cv2 = pytest.importorskip("cv2")
    from kincal.measure.camera_images import detect_board

    png = tmp_path / "board.png"
    code, out, err = run(capsys, "board", kind, "-o", png, "--dpi", DPI, *opts)
    assert code == 0, err
    board = read_board(tmp_path / "board.yaml")
    R, t = _view(board, tilt)
    img = _photograph(cv2, png, board, R, t, np.random.default_rng(7))
    ids, uv = detect_board(cv2, img, board)
    assert len(ids) == board.num_corners and len(set(ids.tolist())) == len(ids)
    truth = _project(board.corner_points(ids), R, t)
    if turns and np.linalg.norm(uv - truth, axis=1).mean() > 5:
        truth = _project(board.corner_points(board.num_corners - 1 - ids), R, t)
    err_px = np.linalg.norm(uv - truth, axis=1)
    # measured with OpenCV 5.0: 0.015-0.04 px mean, 0.04-0.09 px max for every kind
    assert err_px.mean() < tol / 2 and err_px.max() < tol, (err_px.mean(), err_px.max())


def test_page_size_png_pixels_and_pdf_mediabox(tmp_path: Path, capsys) -> None:
    """ChArUco 5 x 7 squares of 30 mm with a 12 mm margin: a 174 x 234 mm page (by hand);
    the PDF's MediaBox is that in points (72 per inch), the PNG has ceil(size / pixel)
    pixels and records its dpi; the JSON says the same."""
    pytest.importorskip("cv2")
    from PIL import Image

    common = ["--square", "30mm", "--marker", "22mm", "--margin", "12mm"]
    code, out, err = run(capsys, "board", "charuco", "-o", tmp_path / "b.pdf", *common,
                         "--json", tmp_path / "b.json")
    assert code == 0, err
    assert "page 174.0 x 234.0 mm, fits A4 portrait" in " ".join(out.split())
    box = re.search(rb"/MediaBox \[ *0 0 ([0-9.]+) ([0-9.]+) *\]",
                    (tmp_path / "b.pdf").read_bytes())
    assert box is not None
    assert float(box.group(1)) == pytest.approx(174 / 25.4 * 72, abs=1e-6)
    assert float(box.group(2)) == pytest.approx(234 / 25.4 * 72, abs=1e-6)
    assert json.loads((tmp_path / "b.json").read_text())["page_mm"] == pytest.approx([174, 234])
    code, out, err = run(capsys, "board", "charuco", "-o", tmp_path / "b.png", *common,
                         "--dpi", "150")
    assert code == 0, err
    with Image.open(tmp_path / "b.png") as im:
        assert im.size == (int(np.ceil(174 / 25.4 * 150)), int(np.ceil(234 / 25.4 * 150)))
        assert im.info["dpi"] == pytest.approx((150, 150), abs=0.02)   # whole px per m
        assert im.mode == "L"
    assert f"{im.size[0]} x {im.size[1]} px at 150 dpi" in " ".join(out.split())


def test_rendered_pixels_cover_the_stated_areas() -> None:
    """Grey levels are black area fractions: a chessboard of 10 mm squares at 127 dpi
    (pixel 0.2 mm, squares not a whole number of pixels) has 255 x (1 - black share)
    mean grey over its squares; a disc of 12 mm its area pi r^2 of black."""
    from kincal.measure.board_render import board_shapes, page_layout, render_pixels

    board = Board("chessboard", 3, 3, 0.0101)
    page = page_layout(board, 0.0)
    img = render_pixels(board_shapes(board), page, 127)
    p = 0.0254 / 127
    black = (255.0 - img.astype(float)) / 255.0
    assert black.sum() * p * p == pytest.approx(5 * 0.0101**2, rel=2e-3)  # 5 black squares
    board = Board("circles", 2, 2, 0.02, 0.012)
    img = render_pixels(board_shapes(board), page_layout(board, 0.005), 127)
    black = (255.0 - img.astype(float)) / 255.0
    assert black.sum() * p * p == pytest.approx(4 * np.pi * 0.006**2, rel=3e-3)


@pytest.mark.parametrize("board", [
    Board("charuco", 5, 7, 0.034, 0.028, "DICT_6X6_250"), Board("chessboard", 7, 10, 0.025),
    Board("aruco_grid", 4, 6, 0.045, 0.035, "DICT_4X4_50"),
    Board("aruco_grid", 3, 4, 0.05, 0.04, "DICT_APRILTAG_36H11"),
    Board("circles", 6, 8, 0.025, 0.0125), Board("asymmetric_circles", 4, 11, 0.02, 0.012),
    Board("asymmetric_circles", 4, 5, 0.0333, 0.0)], ids=lambda b: b.kind)
def test_board_file_round_trip(tmp_path: Path, board: Board) -> None:
    f = tmp_path / "b.yaml"
    f.write_text(board_yaml(board))
    back = read_board(f)
    assert (back.kind, back.columns, back.rows, back.dictionary) == (
        board.kind, board.columns, board.rows, board.dictionary)
    assert back.square == pytest.approx(board.square, rel=1e-12)
    assert back.marker == pytest.approx(board.marker, rel=1e-12, abs=0.0)


def test_circle_grid_geometry_is_opencvs() -> None:
    """OpenCV's calibration sample places the asymmetric grid's circle (row i, j-th in
    the row) at ((2 j + i mod 2) s, i s) and the symmetric one's at (j s, i s); so the
    nearest neighbours of an asymmetric grid are s sqrt(2) apart, a row's 2 s."""
    a = Board("asymmetric_circles", 4, 11, 0.02, 0.012)
    P = a.corner_points(np.arange(44))
    ref = np.array([[(2 * j + i % 2) * 0.02, i * 0.02, 0.0] for i in range(11)
                    for j in range(4)])
    assert np.abs(P - ref).max() < 1e-15
    d = np.linalg.norm(P[:, None] - P[None], axis=2) + np.eye(44)
    assert d.min() == pytest.approx(0.02 * np.sqrt(2))
    s = Board("circles", 6, 8, 0.025, 0.0125).corner_points([0, 1, 6, 47])
    assert np.allclose(s[:, :2], [[0, 0], [0.025, 0], [0, 0.025], [0.125, 0.175]])
    assert a.extent() == pytest.approx((-0.006, -0.006, 0.146, 0.206))


def test_circle_grids_through_import_images(tmp_path: Path, capsys) -> None:
    """``kincal board`` -> photographs -> ``kincal import images --board`` the board file
    it wrote: the circles of the photographed board with their ids and board positions,
    a blank image dropped as 'board not found'."""
    cv2 = pytest.importorskip("cv2")
    code, out, err = run(capsys, "board", "asymmetric-circles", "-o", tmp_path / "p.png",
                         "--dpi", DPI)
    assert code == 0, err
    board = read_board(tmp_path / "p.yaml")
    R, t = _view(board, (15, 10, 0))
    img = _photograph(cv2, tmp_path / "p.png", board, R, t, np.random.default_rng(3))
    (tmp_path / "shots").mkdir()
    cv2.imwrite(str(tmp_path / "shots" / "a.png"), img)
    cv2.imwrite(str(tmp_path / "shots" / "b.png"), np.full(img.shape, 200, np.uint8))
    (tmp_path / "j.csv").write_text("image,q1_deg\na.png,1\nb.png,2\n")
    (tmp_path / "cam.yaml").write_text("camera_matrix: {data: [600, 0, 320, 0, 600, 240, 0, "
                                       "0, 1]}\n")
    code, out, err = run(capsys, "import", "images", tmp_path / "shots", "--board",
                         tmp_path / "p.yaml", "--joints", tmp_path / "j.csv", "--intrinsics",
                         tmp_path / "cam.yaml", "-o", tmp_path / "d.csv")
    assert code == 0, err
    text = " ".join(out.split())
    assert "1 images with the board, 44 corners; 1 dropped" in text
    assert "b.png: board not found" in text
    lines = (tmp_path / "d.csv").read_text().splitlines()
    assert any("asymmetric_circles 4x11 circles, spacing 20 mm" in ln for ln in lines)
    head = next(ln for ln in lines if ln.startswith("q1"))
    cols = head.split(",")
    rows = [ln.split(",") for ln in lines[lines.index(head) + 1:]]
    ids = np.array([int(r[cols.index("corner")]) for r in rows])
    P = np.array([[float(r[cols.index(f"target_{c}_m")]) for c in "xyz"] for r in rows])
    uv = np.array([[float(r[cols.index(c)]) for c in ("u_px", "v_px")] for r in rows])
    assert np.array_equal(ids, np.arange(44))
    assert np.allclose(P, board.corner_points(ids), atol=1e-12)
    assert np.linalg.norm(uv - _project(P, R, t), axis=1).max() < 0.2


@pytest.mark.parametrize("args,match", [
    (["hexagons"], "argument KIND: 'hexagons'; use one of charuco, chessboard"),
    (["charuco", "--spacing", "20mm"], "option --spacing: not for a charuco board"),
    (["chessboard", "--square", "30"], "--square: '30' needs a unit"),
    (["charuco", "--square", "30mm", "--marker", "30mm"], "smaller than the square"),
    (["circles", "--spacing", "20mm", "--diameter", "25mm"], "the circles would touch"),
    (["charuco", "--columns", "20", "--rows", "20", "--dictionary", "DICT_4X4_50"],
     "DICT_4X4_50 has 50 markers; this board needs 200"),
    (["aruco-grid", "--dictionary", "DICT_7X7_12"], "not one of OpenCV's"),
    (["chessboard", "-o", "board.jpg"], "the board is written as .pdf or .png"),
    (["chessboard", "--margin", "-1mm"], "option --margin: must be >= 0"),
])
def test_bad_options_are_one_line_and_write_nothing(tmp_path: Path, capsys, monkeypatch,
                                                    args, match) -> None:
    pytest.importorskip("cv2")
    monkeypatch.chdir(tmp_path)
    out = [] if "-o" in args else ["-o", "board.png"]
    code, _, err = run(capsys, "board", *args, *out)
    assert code == 2 and err.strip().count("\n") == 0 and match in err, err
    assert list(tmp_path.iterdir()) == []


def test_circle_board_file_errors(tmp_path: Path) -> None:
    f = tmp_path / "b.yaml"
    for text, match in [("type: circles\ncircles: [4]\nspacing: 2 cm\n", "circles: two"),
                        ("type: asymmetric_circles\ncircles: [4, 2]\nspacing: 2 cm\n",
                         "3 rows at least"),
                        ("type: circles\ncircles: [4, 5]\n", "spacing: missing"),
                        ("type: asymmetric_circles\ncircles: [4, 5]\nspacing: 20 mm\n"
                         "diameter: 29 mm\n", "28.28 mm apart")]:
        f.write_text(text)
        with pytest.raises(KincalError, match=re.escape(match)):
            read_board(f)


def test_without_opencv_boards_without_markers_still_print(tmp_path: Path, capsys,
                                                           monkeypatch) -> None:
    """A chessboard and circle grids are plain NumPy; markers need OpenCV's dictionaries:
    without OpenCV one line says what to install, and nothing is written."""
    import sys

    monkeypatch.setitem(sys.modules, "cv2", None)           # import cv2 -> ImportError
    code, out, err = run(capsys, "board", "circles", "-o", tmp_path / "c.png", "--dpi", 30)
    assert code == 0 and (tmp_path / "c.yaml").is_file(), err
    code, out, err = run(capsys, "board", "charuco", "-o", tmp_path / "m.pdf")
    assert code == 2 and err.strip().count("\n") == 0 and "kincal[camera]" in err
    assert "drawing ArUco markers" in err
    assert not (tmp_path / "m.pdf").exists() and not (tmp_path / "m.yaml").exists()


def test_pdf_squares_are_where_the_board_file_says(tmp_path: Path, capsys) -> None:
    """The PDF's filled squares (its content stream, in points from the bottom-left
    corner): 35 black squares of 25 mm on a 7 x 10 chessboard, the first one's top-left
    corner 10 mm (the margin) from the page's top-left corner."""
    import zlib

    code, out, err = run(capsys, "board", "chessboard", "-o", tmp_path / "c.pdf")
    assert code == 0, err
    raw = (tmp_path / "c.pdf").read_bytes()
    text = b"".join(zlib.decompress(m.group(1)) for m in
                    re.finditer(rb"/FlateDecode.*?stream\r?\n(.*?)\r?\nendstream", raw, re.S))
    num = rb"([-\d.]+) ([-\d.]+)"
    quads = [np.array(q, dtype=float).reshape(4, 2) for q in re.findall(
        num + rb" m\s+" + num + rb" l\s+" + num + rb" l\s+" + num + rb" l\s+h", text)]
    pt = 72 / 25.4                                                   # points per mm
    height = 270 * pt                                                # 250 mm + 2 margins
    black = [q for q in quads if np.ptp(q[:, 0]) < 100 * pt]         # not the white page
    assert len(black) == 35
    for q in black:
        assert np.ptp(q[:, 0]) == pytest.approx(25 * pt, abs=1e-4)
        assert np.ptp(q[:, 1]) == pytest.approx(25 * pt, abs=1e-4)
    first = min(black, key=lambda q: (-q[:, 1].max(), q[:, 0].min()))
    assert first[:, 0].min() == pytest.approx(10 * pt, abs=1e-4)
    assert height - first[:, 1].max() == pytest.approx(10 * pt, abs=1e-4)
