"""The hand-eye report people look at: every image's reprojection error, worst first, and
the worst images with the detected and the predicted board corners drawn over them.

The predicted pixels of image ``i`` are the fitted model's (:mod:`kincal.identify.
hand_eye_lens`): the board's pose in the camera ``B_i = X^-1 C_i Z`` (``C_i = A_i^-1`` with
the camera on the hand, ``A_i`` with it fixed; ``A_i`` the flange pose in the base) and
OpenCV's pinhole + radial-tangential projection of the board points ``B_i P`` through the
fitted intrinsics.  The error of an image is the RMS over its corners of
``|uv_predicted - uv_detected|`` [px]; over the training images' corners together it is
the fit's training RMS, on a held-out image the fit's held-out figure for it.

A picture (:func:`draw_corners`, PNG of the image's own size, the photo in light grey)
shows each detected corner
as a green circle, the predicted one as a red cross, and the error vector magnified
(``gain`` times, stated in the caption) as a yellow line from the detected corner:
sub-pixel errors are invisible at scale 1.  :func:`hand_eye_page` puts the table and the
pictures on one HTML page in the calibration report's style (images embedded).
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.identify.hand_eye_lens import project_lens
from kincal.report.html import _footer, _head, _img
from kincal.spatial import inverse

Array = NDArray[np.float64]

__all__ = ["ImageError", "predicted_pixels", "image_errors", "draw_corners",
           "hand_eye_page", "image_file"]


@dataclass
class ImageError:
    """One image's reprojection: name, held out or not, detected and predicted pixels
    (n, 2) [px], and the RMS / largest corner error [px]."""

    image: str
    held_out: bool
    detected: Array
    predicted: Array

    @property
    def errors(self) -> Array:
        return np.asarray(np.hypot(*(self.predicted - self.detected).T), dtype=float)

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(self.errors**2)))

    @property
    def max_px(self) -> float:
        return float(self.errors.max(initial=0.0))


def predicted_pixels(A: Array, points: Sequence[Array], X: Array, Z: Array, lens: Array,
                     mount: str) -> list[Array]:
    """The fitted model's raw pixels (n_i, 2) [px] of the board ``points`` (n_i, 3) [m] in
    each image (module docstring); ``A`` (N, 4, 4) the flange poses."""
    if mount not in ("hand", "fixed"):
        raise KincalError(f"mount={mount!r}: use 'hand' or 'fixed'")
    C = inverse(A) if mount == "hand" else np.asarray(A, dtype=float)
    Xi = inverse(X)
    out = []
    for Ci, P in zip(C, points, strict=True):
        B = Xi @ Ci @ Z
        out.append(project_lens(P @ B[:3, :3].T + B[:3, 3], lens))
    return out


def image_errors(names: Sequence[str], detected: Sequence[Array], predicted: Sequence[Array],
                 held_out: Sequence[str]) -> list[ImageError]:
    """Every image's :class:`ImageError`, the worst (largest RMS) first."""
    held = set(held_out)
    rows = [ImageError(n, n in held, np.asarray(d, float), np.asarray(p, float))
            for n, d, p in zip(names, detected, predicted, strict=True)]
    return sorted(rows, key=lambda r: -r.rms_px)


def image_file(folder: str | Path, label: str) -> Path:
    """The image file of ``label`` in an image folder: ``FOLDER/LABEL`` or, for a pose
    folder, ``FOLDER/LABEL/image.png``."""
    p = Path(folder) / label
    return p / "image.png" if p.is_dir() else p


def draw_corners(image: Any, row: ImageError, gain: float = 20.0) -> bytes:
    """PNG bytes of ``image`` (grey or BGR, as OpenCV reads it) with the detected corners
    (green circles), the predicted ones (red crosses) and the error vectors x ``gain``
    (yellow) drawn over it (module docstring); same width and height as the image."""
    import cv2

    img = np.asarray(image)
    grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    # the photo in light grey, 4-level steps: the marks stand out and the PNG stays small
    grey = (96 + (grey.astype(np.uint16) * 5 // 8) // 4 * 4).astype(np.uint8)
    img = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    scale = max(1, round(max(img.shape[:2]) / 800))
    for d, p in zip(row.detected, row.predicted, strict=True):
        tip = d + gain * (p - d)
        cv2.line(img, _pt(d), _pt(tip), (0, 215, 255), scale, cv2.LINE_AA)
        cv2.circle(img, _pt(d), 5 * scale, (0, 200, 0), scale, cv2.LINE_AA)
        cv2.drawMarker(img, _pt(p), (0, 0, 255), cv2.MARKER_CROSS, 9 * scale, scale,
                       cv2.LINE_AA)
    text = f"{row.image}: {row.rms_px:.2f} px RMS, {row.max_px:.2f} px max"
    for colour, width in (((0, 0, 0), 4 * scale), ((255, 255, 255), scale)):
        cv2.putText(img, text, (10 * scale, 30 * scale), cv2.FONT_HERSHEY_SIMPLEX,
                    0.8 * scale, colour, width, cv2.LINE_AA)
    ok, png = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise KincalError(f"cannot encode the picture of {row.image} as PNG")
    return bytes(png.tobytes())


def _pt(p: Array) -> tuple[int, int]:
    return (round(float(p[0])), round(float(p[1])))


def hand_eye_page(title: str, summary: Sequence[str], rows: Sequence[ImageError],
                  pictures: Sequence[tuple[ImageError, bytes]], gain: float = 20.0) -> str:
    """The page: ``summary`` lines, the table of every image (worst first: image, training
    or held out, corners, RMS and largest error [px]), then the pictures."""
    parts = [_head(title)]
    parts += [f"<p>{html.escape(s)}</p>" for s in summary]
    parts.append("<h2>Reprojection error of every image, worst first</h2><table><tr>"
                 "<th class='l'>image</th><th class='l'>used for</th><th>corners</th>"
                 "<th>RMS [px]</th><th>max [px]</th></tr>")
    for r in rows:
        parts.append(f"<tr><td class='l'>{html.escape(r.image)}</td><td class='l'>"
                     f"{'held out' if r.held_out else 'training'}</td>"
                     f"<td>{len(r.detected)}</td><td>{r.rms_px:.3f}</td>"
                     f"<td>{r.max_px:.3f}</td></tr>")
    parts.append("</table>")
    if pictures:
        parts.append(f"<h2>The {len(pictures)} worst images</h2><p class='small'>Green "
                     "circles: the corners detected in the image; red crosses: where the "
                     "fitted camera, hand-eye and board put them; yellow: the error, drawn "
                     f"{gain:g} times longer.</p>")
        for r, png in pictures:
            parts.append(f"<h3>{html.escape(r.image)} ({'held out' if r.held_out else 'training'}"
                         f"): {r.rms_px:.3f} px RMS, {r.max_px:.3f} px max</h3>")
            parts.append(_img(png, r.image))
    parts.append(_footer())
    return "\n".join(parts)
