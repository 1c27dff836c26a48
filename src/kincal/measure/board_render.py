"""Printable calibration boards (``kincal board``): a board's black shapes, drawn as
pixels (PNG) or as a vector PDF page of the board's true size.

A board (:class:`~kincal.measure.camera_board.Board`) is a set of black shapes on white,
in its own frame (x along the columns, y down the rows, metres):

* chessboard: the squares ``(i, j)`` with ``i + j`` even (the top-left one black);
* ChArUco: OpenCV's ``CharucoBoard`` layout: its markers (ids and corners from
  ``getIds`` / ``getObjPoints``) in the white squares, the other squares black;
* ArUco / AprilTag grid: marker ``m`` at ``((m mod c) p, floor(m / c) p)``, side ``L``;
* circle grids: a disc of the stated diameter on every centre
  (:meth:`~kincal.measure.camera_board.Board.corner_points`).

A marker is its ``(b + 2) x (b + 2)`` cells (``b`` bits, one black border cell), the
cells' colours OpenCV's (``cv2.aruco.generateImageMarker`` at one pixel per cell), each
black cell a square of side ``L / (b + 2)``.  The page adds a white margin ``w`` round
the pattern's box ``(x0, y0, x1, y1)`` (:meth:`Board.extent`): the page is
``(x1 - x0 + 2 w) x (y1 - y0 + 2 w)``, the board frame's origin at ``(w - x0, w - y0)``
from the page's top-left corner.

Pixels: at ``dpi`` a pixel is ``p = 0.0254 / dpi`` m; the image has
``ceil(width / p) x ceil(height / p)`` pixels (the right and bottom margins grow by less
than a pixel) and pixel ``(i, j)`` covers ``[j p, (j + 1) p) x [i p, (i + 1) p)`` of the
page.  Its grey level is ``255 (1 - a)``, ``a`` the black area fraction of the pixel:
exact for squares (the product of the overlaps along x and y), from an 8 x 8 sub-sampling
for discs.  So board point ``(X, Y)`` is at pixel ``((X + w - x0) / p - 1/2,
(Y + w - y0) / p - 1/2)`` in OpenCV's convention (pixel centres at whole numbers).
The PNG records its dpi; the PDF page is the page's size exactly (``72 / 0.0254`` points
per metre) with the shapes as vector paths: print either at 100 % (no "fit to page").
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.measure.camera_board import CIRCLE_GRIDS, Board

Array = NDArray[np.float64]

__all__ = ["Shapes", "Page", "board_shapes", "page_layout", "render_pixels", "png_bytes",
           "pdf_bytes", "PAPER"]

#: Paper sizes the command names when the page fits (portrait, width x height) [m].
PAPER = {"A4": (0.210, 0.297), "US Letter": (0.2159, 0.2794), "A3": (0.297, 0.420)}


@dataclass(frozen=True)
class Shapes:
    """The black shapes of a board in its frame [m]: squares ``(x0, y0, x1, y1)`` (n, 4)
    and discs ``(cx, cy, radius)`` (m, 3)."""

    rects: Array
    discs: Array


@dataclass(frozen=True)
class Page:
    """A page: its size ``width x height`` [m] and where the board frame's origin is,
    ``(ox, oy)`` [m] from its top-left corner (x right, y down)."""

    width: float
    height: float
    ox: float
    oy: float


def page_layout(board: Board, margin: float) -> Page:
    """The page of ``board`` with a white margin ``margin`` [m] round its pattern."""
    x0, y0, x1, y1 = board.extent()
    return Page(x1 - x0 + 2 * margin, y1 - y0 + 2 * margin, margin - x0, margin - y0)


def _marker_cells(cells: NDArray[np.uint8], x: float, y: float, side: float) -> list[Array]:
    """The black cells of one marker image (one pixel per cell) as squares, each row's
    runs of black cells merged into one rectangle; ``(x, y)`` its top-left corner [m]."""
    n = cells.shape[0]
    c = side / n
    out = []
    for i in range(n):
        black = np.concatenate([[False], cells[i] < 128, [False]])
        edges = np.flatnonzero(np.diff(black.astype(np.int8)))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            out.append(np.array([x + a * c, y + i * c, x + b * c, y + (i + 1) * c]))
    return out


def _dictionary_cells(board: Board, ids: NDArray[np.int64]) -> list[NDArray[np.uint8]]:
    """OpenCV's cell images of markers ``ids`` of the board's dictionary."""
    from kincal.measure.camera_images import aruco_dictionary, require_opencv

    cv2 = require_opencv("drawing ArUco markers")
    d = aruco_dictionary(cv2, board.dictionary)
    available = len(d.bytesList)
    if len(ids) and int(ids.max()) >= available:
        raise KincalError(f"{board.dictionary} has {available} markers; this board needs "
                          f"{int(ids.max()) + 1}: use fewer squares or a larger dictionary")
    n = int(d.markerSize) + 2
    return [np.asarray(cv2.aruco.generateImageMarker(d, int(m), n), dtype=np.uint8)
            for m in ids]


def board_shapes(board: Board) -> Shapes:
    """The black shapes of ``board`` (module docstring); OpenCV (``kincal[camera]``) for
    the markers of ChArUco boards and marker grids."""
    rects: list[Array] = []
    discs = np.zeros((0, 3))
    s = board.square
    if board.kind in CIRCLE_GRIDS:
        if board.marker <= 0:
            raise KincalError("a circle grid to print needs the circles' diameter")
        c = board.corner_points(np.arange(board.num_corners))
        discs = np.column_stack([c[:, :2], np.full(len(c), board.marker / 2)])
    elif board.kind == "aruco_grid":
        ids = np.arange(board.columns * board.rows, dtype=np.int64)
        for m, cells in zip(ids, _dictionary_cells(board, ids), strict=True):
            rects += _marker_cells(cells, (m % board.columns) * s, (m // board.columns) * s,
                                   board.marker)
    elif board.kind == "charuco":
        from kincal.measure.camera_images import aruco_dictionary, require_opencv

        cv2 = require_opencv("drawing ArUco markers")
        need = board.columns * board.rows // 2
        d = aruco_dictionary(cv2, board.dictionary)
        if need > len(d.bytesList):
            raise KincalError(f"{board.dictionary} has {len(d.bytesList)} markers; this "
                              f"board needs {need}: use fewer squares or a larger dictionary")
        cb = cv2.aruco.CharucoBoard((board.columns, board.rows), s, board.marker, d)
        ids = np.asarray(cb.getIds(), dtype=np.int64).reshape(-1)
        corners = np.asarray(cb.getObjPoints(), dtype=float).reshape(-1, 4, 3)
        white = set()
        for cells, q in zip(_dictionary_cells(board, ids), corners, strict=True):
            centre = q[:, :2].mean(axis=0)
            white.add((int(centre[1] // s), int(centre[0] // s)))
            rects += _marker_cells(cells, float(q[0, 0]), float(q[0, 1]), board.marker)
        rects += [np.array([j * s, i * s, (j + 1) * s, (i + 1) * s])
                  for i in range(board.rows) for j in range(board.columns)
                  if (i, j) not in white]
    else:
        rects += [np.array([j * s, i * s, (j + 1) * s, (i + 1) * s])
                  for i in range(board.rows) for j in range(board.columns) if (i + j) % 2 == 0]
    return Shapes(np.array(rects).reshape(-1, 4), discs)


def _overlap(a: float, b: float, n: int, pitch: float) -> tuple[int, Array]:
    """First pixel and the fractions of pixels ``first ...`` covered by ``[a, b]`` [m]
    (pixel ``k`` spans ``[k p, (k + 1) p)``)."""
    k0 = max(int(math.floor(a / pitch)), 0)
    k1 = min(int(math.ceil(b / pitch)), n)
    k = np.arange(k0, k1)
    lo = np.maximum(k * pitch, a)
    hi = np.minimum((k + 1) * pitch, b)
    return k0, np.clip((hi - lo) / pitch, 0.0, 1.0)


def render_pixels(shapes: Shapes, page: Page, dpi: float) -> NDArray[np.uint8]:
    """The page as 8-bit grey pixels at ``dpi`` (module docstring for the geometry and the
    grey levels); ``(rows, columns) = (ceil(height / p), ceil(width / p))``."""
    pitch = 0.0254 / dpi
    w = int(math.ceil(page.width / pitch - 1e-9))
    h = int(math.ceil(page.height / pitch - 1e-9))
    if w * h > 40e6:
        raise KincalError(f"{w} x {h} pixels is too large an image (40 million at most): "
                          "lower --dpi, or write the PDF, which has no pixels")
    black = np.zeros((h, w), dtype=np.float32)
    for x0, y0, x1, y1 in shapes.rects:
        j0, fx = _overlap(x0 + page.ox, x1 + page.ox, w, pitch)
        i0, fy = _overlap(y0 + page.oy, y1 + page.oy, h, pitch)
        black[i0:i0 + len(fy), j0:j0 + len(fx)] += fy[:, None] * fx[None, :]
    sub = (np.arange(8) + 0.5) / 8
    for cx, cy, r in shapes.discs:
        x, y = cx + page.ox, cy + page.oy
        j0, j1 = max(int((x - r) / pitch), 0), min(int(math.ceil((x + r) / pitch)), w)
        i0, i1 = max(int((y - r) / pitch), 0), min(int(math.ceil((y + r) / pitch)), h)
        px = ((np.arange(j0, j1)[:, None] + sub[None, :]) * pitch - x).reshape(-1)
        py = ((np.arange(i0, i1)[:, None] + sub[None, :]) * pitch - y).reshape(-1)
        inside = (py[:, None] ** 2 + px[None, :] ** 2) <= r * r
        cover = inside.reshape(i1 - i0, 8, j1 - j0, 8).mean(axis=(1, 3))
        black[i0:i1, j0:j1] += cover
    return np.asarray(np.round(255.0 * (1.0 - np.clip(black, 0.0, 1.0))), dtype=np.uint8)


def png_bytes(pixels: NDArray[np.uint8], dpi: float) -> bytes:
    """An 8-bit grey PNG recording its resolution (``dpi``), so that it prints at size."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(pixels, mode="L").save(buf, format="PNG", dpi=(dpi, dpi))
    return buf.getvalue()


def pdf_bytes(shapes: Shapes, page: Page, title: str = "") -> bytes:
    """One PDF page of exactly ``page.width x page.height`` (module docstring), the
    shapes as filled vector paths, nothing else on the page."""
    from matplotlib.collections import PatchCollection
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, Rectangle

    fig = Figure(figsize=(page.width / 0.0254, page.height / 0.0254))
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(0.0, page.width)
    ax.set_ylim(page.height, 0.0)                       # y down, as on the board
    ax.set_axis_off()
    patches: list[Any] = [Rectangle((x0 + page.ox, y0 + page.oy), x1 - x0, y1 - y0)
                          for x0, y0, x1, y1 in shapes.rects]
    patches += [Circle((cx + page.ox, cy + page.oy), r) for cx, cy, r in shapes.discs]
    ax.add_collection(PatchCollection(patches, facecolor="black", edgecolor="none",
                                      linewidth=0.0))
    buf = io.BytesIO()
    fig.savefig(buf, format="pdf", metadata={"Title": title, "Creator": "kincal"})
    return buf.getvalue()
