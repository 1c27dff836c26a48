"""Calibration boards: the description file, the corner positions, a board's pose from pixels.

A board is described by a small YAML file (lengths with their unit)::

    type: charuco            # charuco | chessboard (circle and marker grids below)
    squares: [5, 7]          # squares along x (columns) and y (rows)
    square: 34 mm            # side of one square
    marker: 28 mm            # charuco only: side of the ArUco marker in a white square
    dictionary: DICT_6X6_250 # charuco only: OpenCV's ArUco dictionary

(the keys of OpenCV's and other capture tools' board files are accepted too:
``board_size``, ``square_length``, ``marker_length`` in metres, ``aruco_dictionary``).

A grid of ArUco or AprilTag markers (``type: aruco_grid`` or ``apriltag_grid``)::

    type: apriltag_grid      # or aruco_grid
    markers: [4, 6]          # markers along x (columns) and y (rows)
    marker: 40 mm            # side of a marker (its black border included)
    separation: 10 mm        # gap between two markers
    dictionary: DICT_APRILTAG_36H11   # default; DICT_6X6_250 for an aruco_grid

has marker ``m`` (OpenCV's GridBoard numbering, ids from 0) at column ``m mod c``, row
``floor(m / c)``; its corner ``j`` (0 top-left, 1 top-right, 2 bottom-right, 3
bottom-left, as OpenCV orders them) has the id ``4 m + j`` and sits at
``((m mod c) p + L [j in {1, 2}], floor(m / c) p + L [j in {2, 3}], 0)``, ``L`` the marker
side, ``p = L + separation`` the pitch.

A grid of printed circles, symmetric (``type: circles``) or asymmetric
(``type: asymmetric_circles``), dark circles on white::

    type: asymmetric_circles # or circles
    circles: [4, 11]         # OpenCV's pattern size: circles in a row, number of rows
    spacing: 20 mm           # see below
    diameter: 12 mm          # printed circle diameter (for `kincal board`; < the spacing)

has circle ``k`` (OpenCV's ``findCirclesGrid`` order, row by row from 0, ``c`` circles in
a row) with its centre at::

    circles:             X_k = (k mod c) s,                          Y_k = floor(k / c) s
    asymmetric_circles:  X_k = (2 (k mod c) + floor(k / c) mod 2) s,  Y_k = floor(k / c) s

``s`` the spacing: on a symmetric grid the distance between neighbouring circles; on an
asymmetric grid (OpenCV's layout, every other row shifted by half a row pitch) the
distance between two rows and *half* the distance between two circles of one row, as in
OpenCV's calibration sample (its ``squareSize``); the nearest circles are ``s sqrt(2)``
apart.  A symmetric grid, like a chessboard, has no absolute origin (its 180-degree turn
is a valid detection); an asymmetric one with an odd number of rows has.  The circle's
centre is found as the centre of its blob, which under perspective is not exactly the
image of the circle's centre: the bias grows with the circle's size in the image and the
board's tilt (on rendered images, 0.05 px at most for circles 20-35 px across seen tilted
by 30 deg).

Corner ``k`` is an inner corner of the square grid, numbered row by row as OpenCV numbers
ChArUco corners (and chessboard corners); its position in the board frame (z = 0 on the
printed face, x along the columns) is::

    X_k = ((k mod (c - 1)) + 1) s,     Y_k = (floor(k / (c - 1)) + 1) s,     Z_k = 0   [m]

with ``c`` the number of squares along x and ``s`` the square side.  A chessboard has no
absolute origin: its 180-degree turn is a valid detection as well, so a chessboard suits a
camera that sees the board from one side only.

:func:`board_pose` finds the board's pose in the camera frame from undistorted pixels
(plane-to-image homography, then Gauss-Newton on the reprojection error): the per-image
poses the closed-form hand-eye start needs.  No OpenCV here: this module is plain NumPy.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.spatial import exp_so3

Array = NDArray[np.float64]

BOARD_TYPES = ("charuco", "chessboard", "aruco_grid", "apriltag_grid", "circles",
               "asymmetric_circles")
#: Board kinds whose features are circle centres (OpenCV's ``findCirclesGrid``).
CIRCLE_GRIDS = ("circles", "asymmetric_circles")

_LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "in": 0.0254}
_DICT_NUMBERS = {10: "DICT_6X6_250", 0: "DICT_4X4_50", 1: "DICT_4X4_100", 2: "DICT_4X4_250",
                 4: "DICT_5X5_50", 6: "DICT_5X5_250", 8: "DICT_6X6_50", 9: "DICT_6X6_100",
                 16: "DICT_ARUCO_ORIGINAL"}


@dataclass(frozen=True)
class Board:
    """A planar calibration board.

    Attributes:
        kind: ``"charuco"``, ``"chessboard"``, ``"aruco_grid"`` (ArUco or AprilTag
            markers), ``"circles"`` or ``"asymmetric_circles"``.
        columns, rows: number of squares (markers, circles on a grid) along x and y.
        square: side of a square [m]; on a marker grid the pitch, marker + separation;
            on a circle grid the spacing ``s`` (module docstring).
        marker: side of a ChArUco or grid marker [m] (0 for a chessboard); on a circle
            grid the circle's diameter [m] (0: not stated).
        dictionary: OpenCV ArUco dictionary name (ChArUco), e.g. ``"DICT_6X6_250"``.
    """

    kind: str
    columns: int
    rows: int
    square: float
    marker: float = 0.0
    dictionary: str = ""

    @property
    def num_corners(self) -> int:
        """Inner corners of the square grid: ``(columns - 1) (rows - 1)``; on a marker
        grid the four corners of every marker, ``4 columns rows``; on a circle grid the
        circles, ``columns rows``."""
        if self.kind == "aruco_grid":
            return 4 * self.columns * self.rows
        if self.kind in CIRCLE_GRIDS:
            return self.columns * self.rows
        return (self.columns - 1) * (self.rows - 1)

    def corner_points(self, ids: ArrayLike) -> Array:
        """Board-frame positions (n, 3) [m] of corners ``ids`` (formula in the module doc)."""
        k = np.asarray(ids, dtype=np.int64).reshape(-1)
        if np.any((k < 0) | (k >= self.num_corners)):
            raise KincalError(f"corner id out of range 0..{self.num_corners - 1}")
        if self.kind == "aruco_grid":
            m, c = k // 4, k % 4
            x = (m % self.columns) * self.square + np.where((c == 1) | (c == 2), self.marker, 0)
            y = (m // self.columns) * self.square + np.where(c >= 2, self.marker, 0)
            return np.column_stack([x, y, np.zeros(len(k))]).astype(float)
        if self.kind in CIRCLE_GRIDS:
            row, col = k // self.columns, k % self.columns
            step = (2 * col + row % 2) if self.kind == "asymmetric_circles" else col
            return np.column_stack([step * self.square, row * self.square,
                                    np.zeros(len(k))]).astype(float)
        per_row = self.columns - 1
        return np.column_stack([((k % per_row) + 1) * self.square,
                                ((k // per_row) + 1) * self.square, np.zeros(len(k))])

    def extent(self) -> tuple[float, float, float, float]:
        """The printed pattern's box ``(x0, y0, x1, y1)`` in the board frame [m]: the
        squares of a ChArUco board or a chessboard ``(0, 0, c s, r s)``; the markers of a
        grid ``(0, 0, c p - g, r p - g)`` (``p`` the pitch, ``g = p - L`` the gap); the
        circles of a grid, their outer edges (centres of the first and last circle -/+
        the radius)."""
        if self.kind == "aruco_grid":
            gap = self.square - self.marker
            return (0.0, 0.0, self.columns * self.square - gap, self.rows * self.square - gap)
        if self.kind in CIRCLE_GRIDS:
            r = self.marker / 2
            c = self.corner_points(np.arange(self.num_corners))
            return (-r, -r, float(c[:, 0].max()) + r, float(c[:, 1].max()) + r)
        return (0.0, 0.0, self.columns * self.square, self.rows * self.square)

    def description(self) -> dict[str, Any]:
        """The board file's content (module docstring; lengths as ``'30 mm'``):
        :func:`read_board` of it gives this board back."""
        def mm(v: float) -> str:
            return f"{v * 1e3:.10g} mm"
        if self.kind == "aruco_grid":
            april = self.dictionary.upper().startswith("DICT_APRILTAG")
            return {"type": "apriltag_grid" if april else "aruco_grid",
                    "markers": [self.columns, self.rows], "marker": mm(self.marker),
                    "separation": mm(self.square - self.marker),
                    "dictionary": self.dictionary}
        if self.kind in CIRCLE_GRIDS:
            out: dict[str, Any] = {"type": self.kind, "circles": [self.columns, self.rows],
                                   "spacing": mm(self.square)}
            return out | ({"diameter": mm(self.marker)} if self.marker > 0 else {})
        out = {"type": self.kind, "squares": [self.columns, self.rows],
               "square": mm(self.square)}
        if self.kind == "charuco":
            out |= {"marker": mm(self.marker), "dictionary": self.dictionary}
        return out


def board_yaml(board: Board) -> str:
    """``board``'s description file (YAML, :meth:`Board.description`), headed by a
    comment saying what reads it."""
    return ("# kincal board file: kincal import images --board THIS_FILE\n"
            + yaml.safe_dump(board.description(), sort_keys=False, default_flow_style=None))


def _length(value: Any, key: str, source: str) -> float:
    """``34 mm`` / ``0.034`` (metres) / ``3.4 cm`` -> metres."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        v = float(value)
    else:
        m = re.fullmatch(r"\s*([-+0-9.eE]+)\s*([a-z]+)\s*", str(value))
        if m is None or m.group(2) not in _LENGTH_UNITS:
            raise KincalError(f"{key}: {value!r} is not a length (e.g. '34 mm', '0.034 m')",
                              source=source)
        try:
            v = float(m.group(1)) * _LENGTH_UNITS[m.group(2)]
        except ValueError:
            raise KincalError(f"{key}: {value!r} is not a length", source=source) from None
    if not np.isfinite(v) or v <= 0:
        raise KincalError(f"{key}: must be a positive length, got {value!r}", source=source)
    return v


def _dictionary(d: Any, src: str) -> str:
    name = _DICT_NUMBERS.get(d, "") if isinstance(d, int) else str(d).upper()
    if not re.fullmatch(r"DICT_[A-Z0-9_]+", name):
        raise KincalError(f"dictionary: {d!r} is not an OpenCV ArUco dictionary name "
                          "(e.g. DICT_6X6_250, DICT_APRILTAG_36H11)", source=src)
    return name


def _grid_board(data: dict[str, Any], kind: str, src: str) -> Board:
    """``markers: [columns, rows]``, ``marker`` (side), ``separation`` (gap between
    markers), ``dictionary`` (default ``DICT_APRILTAG_36H11`` for an AprilTag grid)."""
    markers = data.get("markers")
    if (not isinstance(markers, list) or len(markers) != 2
            or not all(isinstance(v, int) and v >= 1 for v in markers)
            or markers[0] * markers[1] < 2):
        raise KincalError("markers: two whole numbers (columns, rows), e.g. [4, 6]",
                          source=src)
    for key in ("marker", "separation"):
        if key not in data:
            raise KincalError(f"{key}: missing (a length, e.g. '40 mm')", source=src)
    marker = _length(data["marker"], "marker", src)
    gap = _length(data["separation"], "separation", src)
    default = "DICT_APRILTAG_36H11" if kind == "apriltag_grid" else "DICT_6X6_250"
    name = _dictionary(data.get("dictionary", default), src)
    return Board("aruco_grid", int(markers[0]), int(markers[1]), marker + gap, marker, name)


def _circle_board(data: dict[str, Any], kind: str, src: str) -> Board:
    """``circles: [per_row, rows]``, ``spacing`` and the optional ``diameter``."""
    circles = data.get("circles")
    least = 2 if kind == "circles" else 1
    if (not isinstance(circles, list) or len(circles) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v >= least
                       for v in circles) or circles[0] * circles[1] < 4
            or (kind == "asymmetric_circles" and circles[1] < 3)):
        raise KincalError("circles: two whole numbers (circles in a row, rows), e.g. [4, 11]"
                          " (4 circles at least; an asymmetric grid has 3 rows at least)",
                          source=src)
    if "spacing" not in data:
        raise KincalError("spacing: missing (a length, e.g. '20 mm')", source=src)
    spacing = _length(data["spacing"], "spacing", src)
    diameter = _length(data["diameter"], "diameter", src) if "diameter" in data else 0.0
    nearest = spacing * (np.sqrt(2.0) if kind == "asymmetric_circles" else 1.0)
    if diameter >= nearest:
        raise KincalError(f"diameter: the circles would touch (the nearest centres are "
                          f"{nearest * 1e3:.4g} mm apart)", source=src)
    return Board(kind, int(circles[0]), int(circles[1]), spacing, diameter)


def read_board(path: str | Path) -> Board:
    """Read a board description (module docstring); a bad file raises one line naming it."""
    src = str(path)
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise KincalError("no such board file", source=src) from None
    except yaml.YAMLError as exc:
        raise KincalError(f"not valid YAML ({' '.join(str(exc).split())})", source=src) from None
    return board_from_mapping(data, src)


def board_from_mapping(data: Any, src: str) -> Board:
    """The board a description's mapping states (module docstring; lengths in metres or
    with their unit); a bad one raises one line prefixed by ``src``."""
    if not isinstance(data, dict):
        raise KincalError("a board file is a mapping (type, squares, square, ...)", source=src)
    kind = str(data.get("type", "charuco" if "marker_length" in data or "marker" in data
                        else "")).lower()
    if kind not in BOARD_TYPES:
        raise KincalError(f"type: {kind or '(missing)'!r}; use one of {', '.join(BOARD_TYPES)}",
                          source=src)
    if kind in ("aruco_grid", "apriltag_grid"):
        return _grid_board(data, kind, src)
    if kind in CIRCLE_GRIDS:
        return _circle_board(data, kind, src)
    squares = data.get("squares", data.get("board_size"))
    if (not isinstance(squares, list) or len(squares) != 2
            or not all(isinstance(v, int) and v >= 2 for v in squares)):
        raise KincalError("squares: two whole numbers >= 2 (columns, rows), e.g. [5, 7]",
                          source=src)
    sq_key = "square" if "square" in data else "square_length"
    if sq_key not in data:
        raise KincalError("square: the side of one square is missing (e.g. '34 mm')",
                          source=src)
    square = _length(data[sq_key], sq_key, src)
    if kind == "chessboard":
        return Board(kind, int(squares[0]), int(squares[1]), square)
    mk_key = "marker" if "marker" in data else "marker_length"
    if mk_key not in data:
        raise KincalError("marker: the ArUco marker side is missing (e.g. '28 mm')",
                          source=src)
    marker = _length(data[mk_key], mk_key, src)
    if marker >= square:
        raise KincalError(f"{mk_key}: the marker must be smaller than the square", source=src)
    d = data.get("dictionary", data.get("aruco_dictionary", "DICT_6X6_250"))
    name = _dictionary(d, src)
    return Board(kind, int(squares[0]), int(squares[1]), square, marker, name)


# ---------------------------------------------------------------------------- pose from pixels
def _project(R: Array, t: Array, P: Array, K: Array) -> Array:
    x = P @ R.T + t
    return np.column_stack([K[0] * x[:, 0] / x[:, 2] + K[2], K[1] * x[:, 1] / x[:, 2] + K[3]])


def _homography(P: Array, n: Array) -> Array:
    """DLT homography from board (X, Y) to normalised image coordinates (Hartley scaled)."""
    def norm(a: Array) -> Array:
        c = a.mean(0)
        s = np.sqrt(2.0) / max(float(np.mean(np.linalg.norm(a - c, axis=1))), 1e-12)
        return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])
    Ta, Tb = norm(P), norm(n)
    a = np.column_stack([P, np.ones(len(P))]) @ Ta.T
    b = np.column_stack([n, np.ones(len(n))]) @ Tb.T
    z = np.zeros((len(P), 3))
    A = np.vstack([np.hstack([a, z, -b[:, :1] * a]), np.hstack([z, a, -b[:, 1:2] * a])])
    H = np.linalg.svd(A)[2][-1].reshape(3, 3)
    return np.asarray(np.linalg.solve(Tb, H @ Ta), dtype=float)


def board_pose(points: ArrayLike, uv: ArrayLike, intrinsics: ArrayLike,
               iterations: int = 20) -> tuple[Array, float]:
    """Pose of a planar board in the camera frame from undistorted pixels.

    ``points`` (n, 3) on the board plane z = 0 [m], ``uv`` (n, 2) [px], ``intrinsics``
    ``(fx, fy, cx, cy)`` [px].  Start: the homography ``H ~ [r1 r2 t]`` of the normalised
    coordinates ``((u - cx)/fx, (v - cy)/fy)``, scaled so ``|r1| = |r2| = 1`` on average,
    ``t_z > 0``, the rotation ``[r1 r2 r1 x r2]`` projected on SO(3) by SVD; then
    Gauss-Newton on the pixel residuals over ``(t, omega)`` with ``R <- exp(omega) R``.

    Returns the 4x4 camera-from-board transform [m] and the RMS reprojection error [px].
    Needs at least 4 points not on one line.
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    obs = np.asarray(uv, dtype=float).reshape(-1, 2)
    K = np.asarray(intrinsics, dtype=float).reshape(4)
    if len(P) < 4:
        raise KincalError("a board pose needs at least 4 corners")
    n = np.column_stack([(obs[:, 0] - K[2]) / K[0], (obs[:, 1] - K[3]) / K[1]])
    H = _homography(P[:, :2], n)
    lam = 2.0 / (np.linalg.norm(H[:, 0]) + np.linalg.norm(H[:, 1]))
    H = H * lam * (1.0 if H[2, 2] > 0 else -1.0)
    M = np.column_stack([H[:, 0], H[:, 1], np.cross(H[:, 0], H[:, 1])])
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    t = H[:, 2].copy()
    r = (_project(R, t, P, K) - obs).reshape(-1)
    for _ in range(iterations):
        x = P @ R.T + t
        z = x[:, 2]
        D = np.zeros((len(P), 2, 3))        # d uv / d x
        D[:, 0, 0] = K[0] / z
        D[:, 0, 2] = -K[0] * x[:, 0] / z**2
        D[:, 1, 1] = K[1] / z
        D[:, 1, 2] = -K[1] * x[:, 1] / z**2
        w = P @ R.T                          # d x / d omega = -[w]x
        Dw = np.zeros((len(P), 3, 3))
        Dw[:, 0, 1], Dw[:, 0, 2] = w[:, 2], -w[:, 1]
        Dw[:, 1, 0], Dw[:, 1, 2] = -w[:, 2], w[:, 0]
        Dw[:, 2, 0], Dw[:, 2, 1] = w[:, 1], -w[:, 0]
        J = np.concatenate([D, D @ Dw], axis=2).reshape(-1, 6)
        step = np.linalg.lstsq(J, -r, rcond=None)[0]
        t = t + step[:3]
        R = exp_so3(step[3:]) @ R
        r_new = (_project(R, t, P, K) - obs).reshape(-1)
        done = abs(float(r @ r) - float(r_new @ r_new)) <= 1e-14 * (1.0 + float(r @ r))
        r = r_new
        if done or np.linalg.norm(step) < 1e-13:
            break
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    if not np.all(np.isfinite(T)) or t[2] <= 0:
        raise KincalError("the board pose could not be found from these corners")
    return T, float(np.sqrt(np.mean(r**2) * 2.0))
