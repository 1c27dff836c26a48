"""Board images in, a camera measurement file out (``kincal import images``).

Every image of a folder is searched for the board (:mod:`kincal.measure.camera_board`)
with OpenCV (the optional extra ``kincal[camera]``, imported only here and only when an
image is read): ChArUco corners by ``cv2.aruco.CharucoDetector``, chessboard corners by
``cv2.findChessboardCorners``, both refined by ``cv2.cornerSubPix`` (window kept off the
ChArUco markers, see :func:`_refine`); the corners of ArUco / AprilTag grid markers by
``cv2.aruco.ArucoDetector``, refined as the intersections of the markers' edge lines
(:func:`_edge_refine`); the centres of symmetric and asymmetric circle grids by
``cv2.findCirclesGrid`` (:func:`_detect_circles`). An image is dropped, with its reason,
when it cannot be read, the board is not found, fewer than ``min_corners`` corners are
seen, the board is blurred
(:func:`board_sharpness` under ``min_sharpness``, default 0.15 px^-3) or, once the
intrinsics are known, seen too obliquely (:func:`drop_oblique`: more than 60 deg between
its normal and the viewing ray by default).

Two folder layouts:

* image files (``.png .jpg .jpeg .bmp``), the joint values in ``--joints joints.csv``: a
  column ``image`` (the file name) and one column per joint with its unit
  (``q1_rad ...`` or ``q1_deg ...``);
* one sub-folder per pose holding ``image.png`` and ``data.json`` (franka-handeye's
  capture layout): the joint values from ``joint_pose`` [rad], the intrinsics from
  ``camera_intrinsics`` (3x3) and ``dist_coeffs`` (k1 k2 p1 p2 k3) when no
  ``--intrinsics`` file is given.

Intrinsics: given (``--intrinsics``: a ROS ``camera_info`` YAML or an OpenCV YAML with
``camera_matrix`` and ``distortion_coefficients``), from the pose folders, or estimated
from the detections by ``cv2.calibrateCamera`` (pinhole + k1 k2 p1 p2 k3).  The lens model
is ROS's ``distortion_model``: ``plumb_bob`` / ``rational_polynomial`` (OpenCV's
radial-tangential, 4, 5 or 8 coefficients) or ``equidistant`` (OpenCV's fisheye, k1 k2 k3
k4; in an OpenCV YAML ``fisheye_model: 1`` as OpenCV's calibration sample writes it).
The file holds *undistorted* pixels, ``u = fx x / z + cx``, ``v = fy y / z + cy`` (the
pinhole model of :mod:`kincal.measure.instruments.camera`, ``mount=hand``), one row per
corner: the joint values, the corner's position on the board ``target_x/y/z``, ``u, v``,
the intrinsics, ``sigma`` and the bookkeeping columns ``image`` and ``corner`` (its id).
"""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.camera_board import CIRCLE_GRIDS, Board
from kincal.measure.instruments.camera import INTRINSICS, HandCameraMeasurement
from kincal.measure.instruments.csvio import block_tags, write_block_table
from kincal.units import UNITS

Array = NDArray[np.float64]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")

__all__ = ["Intrinsics", "Detection", "ImageSet", "require_opencv", "read_intrinsics",
           "detect_images", "detect_gray", "write_image_measurements", "read_image_labels",
           "read_flange_poses", "board_sharpness", "tilt_deg", "drop_oblique"]


def require_opencv(what: str = "reading board images") -> Any:
    """``cv2``, or one line telling how to install it for ``what`` (exit 2)."""
    try:
        import cv2
    except ImportError:
        raise KincalError(f"{what} needs OpenCV: pip install 'kincal[camera]'") from None
    return cv2


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics ``fx, fy, cx, cy`` [px], OpenCV distortion ``k1 k2 p1 p2 k3``
    [1] (``model="equidistant"``: the fisheye's ``k1 k2 k3 k4``) and where they came
    from."""

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    source: str = "given"
    model: str = "plumb_bob"

    @property
    def matrix(self) -> Array:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def pinhole(self) -> tuple[float, float, float, float]:
        return (self.fx, self.fy, self.cx, self.cy)


#: ROS ``distortion_model`` values read: OpenCV's radial-tangential and its fisheye.
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")


def intrinsics_from(K: Any, dist: Any, source: str, model: str = "plumb_bob") -> Intrinsics:
    """:class:`Intrinsics` from a 3x3 camera matrix ``K`` (9 numbers, row-major, px) and
    the distortion coefficients of the ROS ``model`` (plumb_bob / rational_polynomial:
    k1 k2 p1 p2 [k3 ...]; equidistant: k1..k4), checked; errors name ``source``."""
    k = np.asarray(K, dtype=float).reshape(-1)
    d = np.asarray(dist if dist is not None else [], dtype=float).reshape(-1)
    if k.size != 9 or not np.all(np.isfinite(k)) or k[0] <= 0 or k[4] <= 0:
        raise KincalError("camera matrix: expected 9 finite numbers with fx, fy > 0",
                          source=source)
    if model == "equidistant":
        if d.size not in (0, 4) or not np.all(np.isfinite(d)):
            raise KincalError("distortion: the equidistant (fisheye) model has 4 "
                              f"coefficients (k1 k2 k3 k4), not {d.size}", source=source)
        d = np.r_[d, np.zeros(4 - d.size)]
    elif d.size not in (0, 4, 5, 8) or not np.all(np.isfinite(d)):
        raise KincalError("distortion: expected 4, 5 or 8 coefficients (k1 k2 p1 p2 [k3 ..])",
                          source=source)
    return Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]),
                      tuple(float(v) for v in d), source, model)


def distortion_model_named(value: Any, source: str) -> str:
    """The ROS ``distortion_model`` named in a file, or one line refusing it."""
    if value is None or value == "":
        return "plumb_bob"
    if not isinstance(value, str) or value not in DISTORTION_MODELS:
        raise KincalError(f"distortion_model: {value!r} is not a lens model kincal reads "
                          f"({', '.join(DISTORTION_MODELS)})", source=source)
    return value


def read_intrinsics(path: str | Path) -> Intrinsics:
    """A ROS ``camera_info`` YAML (``camera_matrix: {data: [9]}``,
    ``distortion_model``, ``distortion_coefficients: {data: [...]}``), an OpenCV
    FileStorage YAML (``camera_matrix``, ``distortion_coefficients``, and
    ``fisheye_model: 1`` or ``distortion_model: equidistant`` for a fisheye), or
    ROS-Industrial industrial_calibration's ``intrinsics: {fx, fy, cx, cy}`` (no
    distortion).  An unknown ``distortion_model`` is refused (one line naming the file and
    the field)."""
    src = str(path)
    if not Path(path).is_file():
        raise KincalError("no such intrinsics file", source=src)
    text = Path(path).read_text(encoding="utf-8")
    if text.lstrip().startswith("%YAML"):                 # OpenCV FileStorage
        cv2 = require_opencv()
        fs = cv2.FileStorage(src, cv2.FILE_STORAGE_READ)
        K, d = fs.getNode("camera_matrix").mat(), fs.getNode("distortion_coefficients").mat()
        named, fish = fs.getNode("distortion_model"), fs.getNode("fisheye_model")
        model = (distortion_model_named(named.string(), src) if not named.empty() else
                 "equidistant" if not fish.empty() and fish.real() != 0 else "plumb_bob")
        fs.release()
        if K is None:
            raise KincalError("no camera_matrix in this OpenCV YAML", source=src)
        return intrinsics_from(K, d, src, model)
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        raise KincalError("not valid YAML", source=src) from None
    cm = data.get("camera_matrix") if isinstance(data, dict) else None
    ic = data.get("intrinsics") if isinstance(data, dict) else None
    if cm is None and isinstance(ic, dict) and all(k in ic for k in ("fx", "fy", "cx", "cy")):
        try:                                  # industrial_calibration's form, no distortion
            fx, fy, cx, cy = (float(ic[k]) for k in ("fx", "fy", "cx", "cy"))
        except (TypeError, ValueError):
            raise KincalError("intrinsics: fx, fy, cx, cy must be numbers", source=src) from None
        return intrinsics_from([fx, 0, cx, 0, fy, cy, 0, 0, 1], None, src)
    if not isinstance(cm, dict) or "data" not in cm:
        raise KincalError("expected camera_matrix: {data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}",
                          source=src)
    dc = data.get("distortion_coefficients", {})
    return intrinsics_from(cm["data"], dc.get("data") if isinstance(dc, dict) else None, src,
                            distortion_model_named(data.get("distortion_model"), src))


@dataclass
class Detection:
    """The board corners found in one image: ids, raw pixels (n, 2) [px], joint values."""

    image: str
    ids: NDArray[np.int64]
    uv: Array
    q: Array


@dataclass
class ImageSet:
    """The detections of a folder, the images dropped (``(image, reason)``), the image
    size [px] and the intrinsics (given, from the pose folders, or estimated)."""

    detections: list[Detection]
    dropped: list[tuple[str, str]]
    size: tuple[int, int]
    intrinsics: Intrinsics | None = None
    notes: list[str] = field(default_factory=list)


def read_joints_csv(path: str | Path) -> dict[str, Array]:
    """``image`` + joint columns with a unit (``q1_rad`` / ``q1_deg``) -> ``{image: q}``
    [rad]."""
    src = str(path)
    try:
        rows = [r for r in csv.reader(Path(path).read_text(encoding="utf-8-sig").splitlines())
                if r and not r[0].lstrip().startswith("#")]
    except FileNotFoundError:
        raise KincalError("no such joints file", source=src) from None
    if not rows or "image" not in [c.strip() for c in rows[0]]:
        raise KincalError("line 1: expected a header with an 'image' column and joint "
                          "columns with units (q1_rad, ...)", source=src)
    head = [c.strip() for c in rows[0]]
    k_img = head.index("image")
    cols: list[tuple[int, float]] = []
    for k, name in enumerate(head):
        if k == k_img:
            continue
        m = re.fullmatch(r".+_([a-z]+)", name)
        if m is None or m.group(1) not in UNITS or UNITS[m.group(1)][0] != "angle":
            raise KincalError(f"line 1, column {k + 1} ({name}): a joint column needs an "
                              "angle unit, e.g. q1_rad or q1_deg", source=src)
        cols.append((k, UNITS[m.group(1)][1]))
    out: dict[str, Array] = {}
    for n, r in enumerate(rows[1:], start=2):
        try:
            out[r[k_img].strip()] = np.array([float(r[k]) * f for k, f in cols])
        except (ValueError, IndexError):
            raise KincalError(f"line {n}: expected {len(head)} columns of numbers",
                              source=src) from None
    return out


def _sources(folder: Path) -> list[tuple[str, Path, Path | None]]:
    """``(label, image, data.json or None)`` in name order."""
    if not folder.is_dir():
        raise KincalError("no such folder", source=str(folder))
    poses = sorted(p for p in folder.iterdir() if p.is_dir() and (p / "data.json").is_file())
    if poses:
        return [(p.name, p / "image.png", p / "data.json") for p in poses]
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise KincalError("no images (.png .jpg .jpeg .bmp) and no pose folders with "
                          "data.json", source=str(folder))
    return [(p.name, p, None) for p in files]


def _refine(cv2: Any, gray: Any, uv: Array, board: Board) -> Array:
    """``cv2.cornerSubPix`` with a half-window of a quarter of the smallest corner
    spacing, and on a ChArUco board 0.8 of the gap between a corner and the markers
    (``(square - marker) / 2``: a window reaching a marker's edge pulls the corner),
    2 to 11 px."""
    d = np.linalg.norm(uv[:, None] - uv[None], axis=2)
    d[d == 0] = np.inf
    spacing = float(d.min())
    half = 0.25 * spacing
    if board.kind == "charuco":
        half = min(half, 0.8 * spacing * (board.square - board.marker) / (2 * board.square))
    win = int(np.clip(half, 2, 11))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    pts = uv.reshape(-1, 1, 2).astype(np.float32)
    out = cv2.cornerSubPix(gray, pts, (win, win), (-1, -1), crit)
    return np.asarray(out, dtype=float).reshape(-1, 2)


def aruco_dictionary(cv2: Any, name: str) -> Any:
    """OpenCV's predefined ArUco dictionary ``name`` (case-insensitive: DICT_APRILTAG_36H11
    is OpenCV's DICT_APRILTAG_36h11), or one line saying it is not one of OpenCV's."""
    found = [a for a in dir(getattr(cv2, "aruco", None)) if a.upper() == name.upper()]
    if not found:
        raise KincalError(f"dictionary {name!r} is not one of OpenCV's")
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, found[0]))


def _bilinear(img: Array, x: Array, y: Array) -> Array:
    x0 = np.clip(np.floor(x).astype(int), 0, img.shape[1] - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, img.shape[0] - 2)
    fx, fy = x - x0, y - y0
    return np.asarray((1 - fy) * ((1 - fx) * img[y0, x0] + fx * img[y0, x0 + 1])
            + fy * ((1 - fx) * img[y0 + 1, x0] + fx * img[y0 + 1, x0 + 1]), dtype=float)


def _edge_refine(gray: Any, quad: Array, bits: int) -> Array:
    """A marker's four corners (4, 2) [px] as the intersections of its four edge lines.
    Along each edge, 21 profiles across it (between 15 % and 85 % of its length), each
    sampled every 0.1 px over half a border bit each side; the edge point is where the
    profile crosses halfway between its dark and bright ends (linear interpolation); a
    line through the points by total least squares.  A blurred straight edge crosses
    halfway at the edge itself, where the rounded tip of a blurred corner pulls a
    corner detector inwards."""
    img = np.asarray(gray, dtype=float)
    centre = quad.mean(axis=0)
    lines = []
    for a, b in ((0, 1), (1, 2), (2, 3), (3, 0)):
        d = quad[b] - quad[a]
        length = float(np.linalg.norm(d))
        n = np.array([d[1], -d[0]]) / length
        if n @ (quad[a] - centre) < 0:
            n = -n                                              # outwards
        half = float(np.clip(0.45 * length / (bits + 2), 1.0, 4.0))
        s = np.arange(-half, half + 1e-9, 0.1)
        p = quad[a] + np.linspace(0.15, 0.85, 21)[:, None] * d
        prof = _bilinear(img, p[:, None, 0] + s * n[0], p[:, None, 1] + s * n[1])
        mid = 0.5 * (prof[:, :3].mean(axis=1) + prof[:, -3:].mean(axis=1))
        above = prof >= mid[:, None]
        j = np.argmax(above, axis=1)                # first sample at or past the midpoint
        ok = above.any(axis=1) & (j > 0)
        if np.count_nonzero(ok) < 5:
            return quad
        rows, j = np.flatnonzero(ok), j[ok]
        lo, hi = prof[rows, j - 1], prof[rows, j]
        f = (mid[rows] - lo) / np.maximum(hi - lo, 1e-9)
        P = p[rows] + (s[j - 1] + 0.1 * f)[:, None] * n
        c = P.mean(axis=0)
        normal = np.linalg.svd(P - c)[2][-1]
        lines.append((normal, float(normal @ c)))
    out = np.zeros((4, 2))
    for k in range(4):                          # corner k: edges (k-1, k) and (k, k+1)
        (n1, c1), (n2, c2) = lines[(k - 1) % 4], lines[k]
        M = np.array([n1, n2])
        if abs(np.linalg.det(M)) < 1e-6:
            return quad
        out[k] = np.linalg.solve(M, [c1, c2])
    return out if np.abs(out - quad).max() < 2.0 else quad


def _detect_grid(cv2: Any, gray: Any, board: Board) -> tuple[NDArray[np.int64], Array]:
    """The four corners of every grid marker found (OpenCV's ArucoDetector with its
    ``CORNER_REFINE_SUBPIX``, then :func:`_edge_refine`), ids ``4 m + j``."""
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(aruco_dictionary(cv2, board.dictionary), params)
    corners, ids, _ = det.detectMarkers(gray)
    if ids is None or len(ids) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    m = np.asarray(ids, dtype=np.int64).reshape(-1)
    bits = int(det.getDictionary().markerSize)
    uv = np.array([_edge_refine(gray, q, bits)
                   for q in np.asarray(corners, dtype=float).reshape(-1, 4, 2)])
    keep = m < board.columns * board.rows            # markers of other boards are ignored
    k = (4 * m[keep, None] + np.arange(4)).reshape(-1)
    order = np.argsort(k, kind="stable")
    return k[order], uv[keep].reshape(-1, 2)[order]


def _detect_circles(cv2: Any, gray: Any, board: Board) -> tuple[NDArray[np.int64], Array]:
    """The circle centres of a circle grid by ``cv2.findCirclesGrid`` (flag
    ``CALIB_CB_SYMMETRIC_GRID`` or ``CALIB_CB_ASYMMETRIC_GRID``; then, if not found, with
    ``CALIB_CB_CLUSTERING`` as well, which copes better with perspective), ids in its
    order (:mod:`~kincal.measure.camera_board`).  The blob detector finds dark blobs of
    any size from 3 px across to a fiftieth of the image area (OpenCV's default stops at
    5000 px^2, about 80 px across: a board held close to the camera); a centre is the
    blob's centroid (no corner refinement: there is no corner)."""
    params = cv2.SimpleBlobDetector_Params()
    params.filterByColor, params.blobColor = True, 0
    params.minArea = 7.0
    params.maxArea = max(float(gray.shape[0] * gray.shape[1]) / 50.0, 100.0)
    params.minDistBetweenBlobs = 2.0
    detector = cv2.SimpleBlobDetector_create(params)
    flag = (cv2.CALIB_CB_ASYMMETRIC_GRID if board.kind == "asymmetric_circles"
            else cv2.CALIB_CB_SYMMETRIC_GRID)
    size = (board.columns, board.rows)
    for flags in (flag, flag + cv2.CALIB_CB_CLUSTERING):
        found, centres = cv2.findCirclesGrid(gray, size, flags=flags, blobDetector=detector)
        if found and centres is not None:
            uv = np.asarray(centres, dtype=float).reshape(-1, 2)
            return np.arange(len(uv), dtype=np.int64), uv
    return np.zeros(0, dtype=np.int64), np.zeros((0, 2))


def detect_board(cv2: Any, gray: Any, board: Board) -> tuple[NDArray[np.int64], Array]:
    """Corner ids and sub-pixel pixels [px] of ``board`` in a grey image (empty if none):
    the corners of a ChArUco board, a chessboard or a marker grid, the circle centres of
    a circle grid."""
    if board.kind == "aruco_grid":
        return _detect_grid(cv2, gray, board)
    if board.kind in CIRCLE_GRIDS:
        return _detect_circles(cv2, gray, board)
    if board.kind == "charuco":
        d = aruco_dictionary(cv2, board.dictionary)
        cb = cv2.aruco.CharucoBoard((board.columns, board.rows), board.square, board.marker, d)
        corners, ids, _, _ = cv2.aruco.CharucoDetector(cb).detectBoard(gray)
        if ids is None or len(ids) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
        uv = np.asarray(corners, dtype=float).reshape(-1, 2)
        return np.asarray(ids, dtype=np.int64).reshape(-1), _refine(cv2, gray, uv, board)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE + cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(gray, (board.columns - 1, board.rows - 1),
                                               flags=flags)
    if not found:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    uv = np.asarray(corners, dtype=float).reshape(-1, 2)
    return np.arange(len(uv), dtype=np.int64), _refine(cv2, gray, uv, board)


#: Default of ``min_sharpness`` (:func:`board_sharpness`, px^-3): the real sets give
#: 2.6-3.5 (Franka, RealSense) and 0.25-0.77 (ABB, one image out of focus at 0.25); a
#: rendered chessboard 0.43 sharp, 0.17 / 0.11 / 0.07 under 8 / 14 / 20 px of motion blur.
MIN_SHARPNESS = 0.15
#: Default of ``max_tilt_deg`` (:func:`drop_oblique`): beyond 60 deg the squares are
#: foreshortened to less than half (cos 60 deg) along the tilt and the corners' sub-pixel
#: windows see skewed edges.  The real sets reach 26 deg (Franka) and 55 deg (ABB).
MAX_TILT_DEG = 60.0


def board_sharpness(cv2: Any, gray: Any, uv: Array) -> float:
    """How sharp the board looks: ``var(Laplacian) s / C^2`` [px^-3] over the convex hull of
    the corners ``uv``: the variance of the 4-neighbour Laplacian of the grey levels,
    times the corner spacing ``s`` [px] (median distance to the nearest corner), over the
    board's contrast ``C`` squared (the 5-95 percentile range of its grey levels).  An
    edge blurred over ``w`` px has a Laplacian ``~ C / w^2`` on a band ``~ w`` wide, one
    such band per square: the figure goes as ``1 / w^3`` whatever the contrast and the
    board's size in the image."""
    hull = cv2.convexHull(uv.astype(np.float32)).astype(np.int32)
    mask = np.zeros(gray.shape, np.uint8)
    cv2.fillConvexPoly(mask, hull, 1)
    inside = mask > 0
    lap = cv2.Laplacian(np.asarray(gray, dtype=np.float64), cv2.CV_64F)[inside]
    grey = np.asarray(gray, dtype=float)[inside]
    C = float(np.percentile(grey, 95) - np.percentile(grey, 5))
    d = np.linalg.norm(uv[:, None] - uv[None], axis=2)
    d[d == 0] = np.inf
    s = float(np.median(d.min(axis=1)))
    return float(lap.var() * s / C**2) if C > 0 else 0.0


def tilt_deg(board: Board, det: Detection, intr: Intrinsics) -> float:
    """Angle [deg] between the board's normal and the viewing ray to the centre of its
    detected corners (board pose from the undistorted pixels)."""
    from kincal.measure.camera_board import board_pose

    P = board.corner_points(det.ids)
    T = board_pose(P, undistort(det.uv, intr), intr.pinhole)[0]
    c = T[:3, :3] @ P.mean(axis=0) + T[:3, 3]
    return float(np.degrees(np.arccos(min(abs(T[:3, 2] @ c) / np.linalg.norm(c), 1.0))))


def drop_oblique(images: ImageSet, board: Board, intr: Intrinsics,
                 max_tilt_deg: float = MAX_TILT_DEG) -> ImageSet:
    """``images`` without the detections whose board is tilted more than ``max_tilt_deg``
    from the viewing ray (:func:`tilt_deg`), each listed as dropped with its angle."""
    keep, dropped = [], list(images.dropped)
    for d in images.detections:
        a = tilt_deg(board, d, intr)
        if a > max_tilt_deg:
            dropped.append((d.image, f"board too oblique ({a:.0f} deg between its normal "
                                     f"and the viewing ray > {max_tilt_deg:g} deg)"))
        else:
            keep.append(d)
    return ImageSet(keep, dropped, images.size, images.intrinsics, images.notes)


def add_detection(cv2: Any, out: Any, label: str, gray: Any, q: Any, board: Board,
                  min_corners: int, min_sharpness: float) -> None:
    """Detect the board in one grey image and put it into ``out`` (an :class:`ImageSet`):
    a :class:`Detection` with the joint values ``q``, or the image's label with the
    reason it was dropped; ``out.size`` becomes the image's (width, height) [px]."""
    out.size = (int(gray.shape[1]), int(gray.shape[0]))
    found = detect_gray(cv2, gray, board, min_corners, min_sharpness)
    if isinstance(found, str):
        out.dropped.append((label, found))
    else:
        out.detections.append(Detection(label, *found, q))


def detect_gray(cv2: Any, gray: Any, board: Board, min_corners: int = 6,
                min_sharpness: float = MIN_SHARPNESS) -> tuple[NDArray[np.int64], Array] | str:
    """The corner ids and pixels [px] of ``board`` in one grey image, or why it is dropped:
    board not found, fewer than ``min_corners`` corners, or blurred
    (:func:`board_sharpness` under ``min_sharpness``)."""
    ids, uv = detect_board(cv2, gray, board)
    if len(ids) == 0:
        return "board not found"
    if len(ids) < min_corners:
        return f"too few corners ({len(ids)} < {min_corners})"
    if (sharp := board_sharpness(cv2, gray, uv)) < min_sharpness:
        return (f"motion blur (sharpness {sharp:.2g} < {min_sharpness:g} px^-3: variance of "
                "the Laplacian on the board x corner spacing / contrast^2)")
    return ids, uv


def detect_images(folder: str | Path, board: Board, joints: Mapping[str, Array] | None = None,
                  min_corners: int = 6, require_joints: bool = True,
                  min_sharpness: float = MIN_SHARPNESS) -> ImageSet:
    """Detect ``board`` in every image of ``folder`` (module docstring for the layouts);
    ``require_joints=False``: images without joint values get an empty ``q`` (for robot
    poses given otherwise, e.g. flange poses of an eye-to-hand set).  An image whose
    board is less sharp than ``min_sharpness`` (:func:`board_sharpness`) is dropped as
    blurred (motion blur: the robot still moving)."""
    cv2 = require_opencv()
    if board.kind == "charuco" and not hasattr(getattr(cv2, "aruco", None), "CharucoDetector"):
        raise KincalError(f"OpenCV {cv2.__version__} has no ChArUco detector; pip install "
                          "'opencv-python-headless>=4.7'")
    if board.kind in ("charuco", "aruco_grid"):
        aruco_dictionary(cv2, board.dictionary)
    out = ImageSet([], [], (0, 0))
    given: list[Intrinsics] = []
    for label, image, data in _sources(Path(folder)):
        q: Array | None = None
        if data is not None:
            d = json.loads(data.read_text(encoding="utf-8"))
            if "joint_pose" in d:
                q = np.asarray(d["joint_pose"], dtype=float)
            if "camera_intrinsics" in d:
                given.append(intrinsics_from(d["camera_intrinsics"], d.get("dist_coeffs"),
                                              str(data)))
        if joints is not None:
            q = joints.get(label, joints.get(image.name))
        if q is None and not require_joints:
            q = np.zeros(0)
        if q is None:
            raise KincalError(f"no joint values for image {label!r} (--joints: a row with "
                              f"image={label})", source=str(folder))
        gray = cv2.imread(str(image), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            out.dropped.append((label, "cannot be read as an image"))
            continue
        add_detection(cv2, out, label, gray, q, board, min_corners, min_sharpness)
    if given:
        first = given[0]
        if any(g.pinhole != first.pinhole or g.dist != first.dist for g in given[1:]):
            raise KincalError("the pose folders state different intrinsics; give one file "
                              "with --intrinsics", source=str(folder))
        out.intrinsics = Intrinsics(*first.pinhole, first.dist, "pose folders (data.json)")
    return out


def estimate_intrinsics(images: ImageSet, board: Board,
                        model: str = "plumb_bob") -> Intrinsics:
    """Pinhole + k1 k2 p1 p2 k3 from the detections by ``cv2.calibrateCamera``; with
    ``model="equidistant"`` the fisheye's k1 k2 k3 k4 by ``cv2.fisheye.calibrate`` (skew
    fixed at 0, the board poses recomputed at every step)."""
    cv2 = require_opencv()
    if len(images.detections) < 3:
        raise KincalError(f"{len(images.detections)} images with the board: estimating "
                          "intrinsics needs 3 at least; give them with --intrinsics")
    if model == "equidistant":
        obj64 = [board.corner_points(d.ids).reshape(1, -1, 3) for d in images.detections]
        img64 = [d.uv.reshape(1, -1, 2).astype(np.float64) for d in images.detections]
        flags = sum(getattr(cv2.fisheye, f, None) or getattr(cv2, f)   # 4.x | 5.x
                    for f in ("CALIB_RECOMPUTE_EXTRINSIC", "CALIB_FIX_SKEW"))
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
        try:
            rms, K, dist, _, _ = cv2.fisheye.calibrate(obj64, img64, images.size, None, None,
                                                       flags=flags, criteria=crit)
        except cv2.error as exc:
            raise KincalError("cv2.fisheye.calibrate failed on these images ("
                              + " ".join(str(exc).split())[-100:] + "); give the "
                              "intrinsics with --intrinsics") from None
        return intrinsics_from(K, dist, f"estimated (cv2.fisheye.calibrate, RMS {rms:.3g} "
                                "px)", "equidistant")
    obj = [board.corner_points(d.ids).astype(np.float32) for d in images.detections]
    img = [d.uv.astype(np.float32).reshape(-1, 1, 2) for d in images.detections]
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, images.size, None, None)
    return intrinsics_from(K, dist, f"estimated (cv2.calibrateCamera, RMS {rms:.3g} px)")


def undistort(uv: Array, intr: Intrinsics) -> Array:
    """Undistorted pixels (the pinhole image of the same rays) [px]; the fisheye's by
    ``cv2.fisheye.undistortPoints``."""
    if not any(intr.dist):
        return uv.copy()
    cv2 = require_opencv()
    if intr.model == "equidistant":
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50, 1e-14)
        fish = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2).astype(np.float64),
                                           intr.matrix, np.asarray(intr.dist, dtype=float),
                                           P=intr.matrix, criteria=crit)
        return np.asarray(fish, dtype=float).reshape(-1, 2)
    out = cv2.undistortPoints(uv.reshape(-1, 1, 2).astype(np.float64), intr.matrix,
                              np.asarray(intr.dist, dtype=float), P=intr.matrix)
    return np.asarray(out, dtype=float).reshape(-1, 2)


def _board_note(board: Board) -> str:
    """The measurement file's comment line naming the board."""
    size = f"board: {board.kind} {board.columns}x{board.rows}"
    if board.kind in CIRCLE_GRIDS:
        return (f"{size} circles, spacing {board.square * 1e3:g} mm; circle centres from "
                "OpenCV (blob centroids)")
    if board.kind == "aruco_grid":
        size += (f" markers of {board.marker * 1e3:g} mm, pitch {board.square * 1e3:g} mm "
                 f"({board.dictionary})")
    else:
        size += f" squares of {board.square * 1e3:g} mm"
    return size + "; corners from OpenCV, sub-pixel"


def write_image_measurements(path: str | Path, images: ImageSet, board: Board,
                             intr: Intrinsics, sigma_px: float = 0.5, robot: Any = None,
                             name: str = "camera") -> HandCameraMeasurement:
    """Write the hand-camera measurement file (module docstring); returns its block."""
    if not images.detections:
        raise KincalError("the board was found in no image; nothing to write")
    ns = {len(d.q) for d in images.detections}
    if len(ns) != 1:
        raise KincalError(f"the images have different numbers of joint values: {sorted(ns)}")
    rows = [len(d.ids) for d in images.detections]
    q = np.repeat(np.array([d.q for d in images.detections]), rows, axis=0)
    s = np.vstack([board.corner_points(d.ids) for d in images.detections])
    uv = np.vstack([undistort(d.uv, intr) for d in images.detections])
    block = HandCameraMeasurement(name, q, s, uv, sigma_px, intr.pinhole)
    cols: list[tuple[str, Any, str]] = [(f"target_{c}", s[:, i], "length")
                                        for i, c in enumerate("xyz")]
    cols += [("u", uv[:, 0], "pixel"), ("v", uv[:, 1], "pixel")]
    cols += [(k, np.full(len(q), v), "pixel") for k, v in zip(INTRINSICS, intr.pinhole,
                                                              strict=True)]
    cols.append(("sigma", block.sigma, "pixel"))
    cols.append(("image", [d.image for d, n in zip(images.detections, rows, strict=True)
                           for _ in range(n)], "text"))
    cols.append(("corner", np.concatenate([d.ids for d in images.detections]), "text"))
    dist = " ".join(f"{v:.6g}" for v in intr.dist)
    write_block_table(path, block_tags("camera", block, mount="hand"), q, cols, None, robot,
                      [_board_note(board),
                       f"intrinsics {intr.source}; distortion ("
                       + ("equidistant k1 k2 k3 k4" if intr.model == "equidistant" else
                          "k1 k2 p1 p2 k3") + f") {dist} "
                       "removed: u = fx x/z + cx, v = fy y/z + cy",
                       f"{len(images.detections)} images, {len(q)} corners; dropped: "
                       + (", ".join(f"{i} ({r})" for i, r in images.dropped) or "none")])
    return block


def read_flange_poses(folder: str | Path) -> dict[str, Array]:
    """``{name: 4x4}`` [m] from a folder of pose files ``NAME.yaml``, each ``x, y, z`` [m]
    and a unit quaternion ``qx, qy, qz, qw`` (ROS-Industrial industrial_calibration's
    form): the flange in the robot's base frame, matched to the image of the same name."""
    from kincal.spatial import quat_to_matrix

    root = Path(folder)
    if not root.is_dir():
        raise KincalError("no such folder of pose files", source=str(folder))
    out: dict[str, Array] = {}
    for f in sorted(root.glob("*.yaml")):
        try:
            d = yaml.safe_load(f.read_text(encoding="utf-8"))
        except yaml.YAMLError:
            raise KincalError("not valid YAML", source=str(f)) from None
        keys = ("x", "y", "z", "qw", "qx", "qy", "qz")
        if not isinstance(d, dict) or any(k not in d for k in keys):
            raise KincalError("a pose file holds x, y, z [m] and qx, qy, qz, qw",
                              source=str(f))
        try:
            v = np.array([float(d[k]) for k in keys])
        except (TypeError, ValueError):
            raise KincalError("x, y, z, qx, qy, qz, qw must be numbers", source=str(f)) from None
        if not np.all(np.isfinite(v)) or abs(np.linalg.norm(v[3:]) - 1.0) > 1e-3:
            raise KincalError("the quaternion qx, qy, qz, qw is not a unit one",
                              source=str(f))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = quat_to_matrix(v[3:]), v[:3]
        out[f.stem] = T
    if not out:
        raise KincalError("no pose files (NAME.yaml)", source=str(folder))
    return out


def read_image_labels(path: str | Path) -> list[str]:
    """The ``image`` column of a measurement file, one label per data row."""
    lines = [ln for ln in Path(path).read_text(encoding="utf-8-sig").splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]
    head = [c.strip() for c in next(csv.reader(lines[:1]))] if lines else []
    if "image" not in head:
        raise MeasurementFileError("no 'image' column: held-out images need the file "
                                   "`kincal import images` writes", source=str(path))
    k = head.index("image")
    return [r[k].strip() for r in csv.reader(lines[1:])]


def sample_labels(labels: Sequence[str]) -> list[str]:
    """The distinct labels in name order (independent of the row order)."""
    return sorted(set(labels))
