"""Orientation conventions of pose files: how three (or four) columns make a rotation.

A pose file's orientation columns are read by the file's ``orientation`` option (a
tag-line entry ``orientation=...``, ``--option orientation=...`` on the command line,
``options: {orientation: ...}`` in a setup file):

==================  ===========================================================
``rpy`` (default)   kincal's roll-pitch-yaw: ``R = Rz(rz) Ry(ry) Rx(rx)`` (fixed
                    axes x, then y, then z; the same as intrinsic ``ZYX``)
``euler:ZYX``       intrinsic (moving-axis) Tait-Bryan sequence, upper case: first
                    about z, then about the new y, then the new x:
                    ``R = Rz(rz) Ry(ry) Rx(rx)``; ``euler:XYZ`` is
                    ``R = Rx(rx) Ry(ry) Rz(rz)``
``euler:xyz``       extrinsic (fixed-axis) sequence, lower case: first about the
                    fixed x, then fixed y, then fixed z: ``R = Rz(rz) Ry(ry) Rx(rx)``
``rotvec``          rotation vector ``(rx, ry, rz) = angle * axis`` in an angle
                    unit: ``R = exp([r]x)``
``quaternion``      columns ``qw qx qy qz`` (any order, unit norm within 1e-3,
                    then normalised); chosen by itself when the file has them
==================  ===========================================================

In an Euler sequence the angle about axis ``x`` is the column ``rx`` (and so on), so
the three axes must differ (Tait-Bryan angles); a proper Euler sequence (``ZYZ``) has two
angles about one axis and no such columns, and is refused.  Upper / lower case follow
``scipy.spatial.transform.Rotation.from_euler``, against which the tests check every
convention.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kincal.errors import MeasurementFileError
from kincal.measure.files import MeasurementTable, read_header
from kincal.spatial import exp_so3, log_so3, rotx, roty, rotz

Array = NDArray[np.float64]

__all__ = ["Orientation", "parse_orientation", "rotation_matrices", "QUATERNION_COLUMNS",
           "ORIENTATIONS"]

#: The quaternion columns (scalar first in the name list; any order in the file).
QUATERNION_COLUMNS = ("qw", "qx", "qy", "qz")

#: How far from 1 a quaternion's norm may be.
QUATERNION_NORM_TOLERANCE = 1e-3

#: The conventions, for messages.
ORIENTATIONS = "rpy, euler:ABC (intrinsic, e.g. ZYX), euler:abc (extrinsic), rotvec, quaternion"

_AXIS = {"x": rotx, "y": roty, "z": rotz}


@dataclass(frozen=True)
class Orientation:
    """A parsed orientation convention.

    Attributes:
        kind: ``rpy``, ``euler``, ``rotvec`` or ``quaternion``.
        sequence: for ``euler``, three axis letters, upper case intrinsic, lower case
            extrinsic (``"ZYX"``, ``"xyz"``).
    """

    kind: str = "rpy"
    sequence: str = ""

    @property
    def text(self) -> str:
        return f"euler:{self.sequence}" if self.kind == "euler" else self.kind

    def matrix_order(self) -> str:
        """The axes in the order their rotations multiply, left to right (``R = R_a R_b
        R_c``): the sequence itself for intrinsic, reversed for extrinsic."""
        if self.kind == "rpy":
            return "zyx"
        s = self.sequence.lower()
        return s if self.sequence.isupper() else s[::-1]


def parse_orientation(text: str | None, what: str = "orientation") -> Orientation:
    """``None`` / ``"rpy"`` / ``"euler:ZYX"`` / ``"rotvec"`` / ``"quaternion"`` ->
    :class:`Orientation`; anything else is one error line listing the conventions."""
    if text is None or not text.strip():
        return Orientation()
    t = text.strip()
    if t.lower() in ("rpy", "rotvec", "quaternion"):
        return Orientation(t.lower())
    if ":" in t and t.split(":", 1)[0].strip().lower() == "euler":
        seq = t.split(":", 1)[1].strip()
        if len(seq) != 3 or not (seq.isupper() or seq.islower()) or \
                set(seq.lower()) - set("xyz"):
            raise MeasurementFileError(f"{what} {t!r}: an Euler sequence is three of x, y, z, "
                                       "upper case (intrinsic, e.g. ZYX) or lower case "
                                       "(extrinsic, e.g. xyz)")
        if len(set(seq.lower())) != 3:
            raise MeasurementFileError(f"{what} {t!r}: a proper Euler sequence has two "
                                       "angles about one axis, which the columns rx, ry, rz "
                                       "cannot hold; use three different axes, rotvec or "
                                       "quaternion")
        return Orientation("euler", seq)
    raise MeasurementFileError(f"{what} {t!r} is not a convention ({ORIENTATIONS})")


def rotation_matrices(orientation: Orientation, angles: dict[str, Array]) -> Array:
    """(N, 3, 3) rotations from the columns of one convention.

    Args:
        orientation: the convention.
        angles: ``{"rx": (N,), "ry": ..., "rz": ...}`` [rad] for ``rpy`` / ``euler`` /
            ``rotvec``; ``{"qw": (N,), "qx": ..., ...}`` for ``quaternion``.

    Formulas: ``euler`` ``R = R_a(r_a) R_b(r_b) R_c(r_c)`` with ``abc`` from
    :meth:`Orientation.matrix_order`; ``rotvec`` ``R = exp([r]x)``; ``quaternion``
    ``R = I + 2 w [v]x + 2 [v]x^2`` for the unit ``(w, v)``.
    """
    if orientation.kind == "quaternion":
        w, x, y, z = (np.asarray(angles[c], dtype=float) for c in QUATERNION_COLUMNS)
        n = np.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / n, x / n, y / n, z / n
        R = np.empty(w.shape + (3, 3))
        R[..., 0, 0] = 1 - 2 * (y * y + z * z)
        R[..., 0, 1] = 2 * (x * y - w * z)
        R[..., 0, 2] = 2 * (x * z + w * y)
        R[..., 1, 0] = 2 * (x * y + w * z)
        R[..., 1, 1] = 1 - 2 * (x * x + z * z)
        R[..., 1, 2] = 2 * (y * z - w * x)
        R[..., 2, 0] = 2 * (x * z - w * y)
        R[..., 2, 1] = 2 * (y * z + w * x)
        R[..., 2, 2] = 1 - 2 * (x * x + y * y)
        return R
    if orientation.kind == "rotvec":
        r = np.stack([angles[c] for c in ("rx", "ry", "rz")], axis=-1)
        return np.asarray(exp_so3(r), dtype=float)
    order = orientation.matrix_order()
    R = np.asarray(_AXIS[order[0]](angles["r" + order[0]]), dtype=float)
    for a in order[1:]:
        R = R @ _AXIS[a](angles["r" + a])
    return R


def quaternion_norm_error(angles: dict[str, Array]) -> tuple[int, float] | None:
    """The first row whose quaternion norm is off 1 by more than
    :data:`QUATERNION_NORM_TOLERANCE` and that norm, else None."""
    q = np.stack([np.asarray(angles[c], dtype=float) for c in QUATERNION_COLUMNS], axis=-1)
    n = np.linalg.norm(q, axis=-1)
    bad = np.abs(n - 1.0) > QUATERNION_NORM_TOLERANCE
    if bad.any():
        i = int(np.argmax(bad))
        return i, float(n[i])
    return None


#: Per-axis standard deviation columns of a pose file: position, then orientation.
AXIS_SIGMAS = (("sigma_x", "sigma_y", "sigma_z"), ("sigma_rx", "sigma_ry", "sigma_rz"))


def pose_rotations(t: MeasurementTable) -> tuple[Array, Orientation]:
    """(N, 3, 3) rotations of a pose table by its ``orientation`` tag (default ``rpy``);
    quaternion columns choose ``quaternion`` by themselves.  A missing column or a
    quaternion far from unit norm is one error line naming the file and line."""
    values, text = t.values, t.tags.get("orientation")
    has_q = [c for c in QUATERNION_COLUMNS if c in values]
    try:
        orient = parse_orientation(text if text is not None or not has_q else "quaternion")
    except MeasurementFileError as exc:
        raise t.error(str(exc), 1) from None
    need = QUATERNION_COLUMNS if orient.kind == "quaternion" else ("rx", "ry", "rz")
    missing = [c for c in need if c not in values]
    if missing:
        unit = "" if orient.kind == "quaternion" else " with its unit, e.g. " + missing[0] + "_deg"
        raise t.error(f"orientation {orient.text}: missing column {missing[0]!r}{unit}")
    if orient.kind == "quaternion":
        bad = quaternion_norm_error(values)
        if bad is not None:
            raise t.error(f"the quaternion's norm is {bad[1]:.6g}, not 1",
                          int(t.lines[bad[0]]))
    return rotation_matrices(orient, values), orient


def quaternion_units(path: str | os.PathLike[str]) -> dict[str, str]:
    """``{"qw": "1", ...}`` for the bare quaternion columns of a file's header (a
    quaternion's components have no unit; a header need not say so)."""
    names = read_header(path)[1]
    return {c: "1" for c in QUATERNION_COLUMNS if c in names}


def angle_axes(orientation: Orientation, angles: dict[str, Array], step: float = 1e-6
               ) -> Array:
    """(N, 3, 3) rotation axes of the three angle columns, in the frame the rotations are
    expressed in: column ``k`` is ``w_k = dR/dr_k R^T`` as a vector, so that small changes
    ``dr`` of ``rx, ry, rz`` [rad] turn ``R`` by ``exp(E dr) R`` (left perturbation).
    By central differences of :func:`rotation_matrices`, ``w_k = log(R(r + h e_k)
    R(r - h e_k)^T) / (2 h)``, exact to ``O(h^2)``; for ``rpy`` / ``euler`` / ``rotvec``."""
    cols = ("rx", "ry", "rz")
    E = np.empty(np.shape(angles["rx"]) + (3, 3))
    for k, c in enumerate(cols):
        hi = {a: angles[a] + (step if a == c else 0.0) for a in cols}
        lo = {a: angles[a] - (step if a == c else 0.0) for a in cols}
        D = rotation_matrices(orientation, hi) @ np.swapaxes(rotation_matrices(orientation,
                                                                               lo), -1, -2)
        E[..., :, k] = log_so3(D) / (2.0 * step)
    return E


@dataclass(frozen=True)
class PoseSigmas:
    """Stated standard deviations of a pose table, per row.

    Attributes:
        position: (N,) one per row (each coordinate), (N, 3) one per instrument axis
            [m], or None.
        orientation: (N,) one per rotation-vector component, (N, 3) one per angle
            column [rad], or None.
        orientation_axes: (N, 3, 3) with per-angle ones: the angles' rotation axes
            (:func:`angle_axes`), so the rotation error's covariance is ``E diag(s^2)
            E^T``; else None.
    """

    position: Array | None
    orientation: Array | None
    orientation_axes: Array | None = None


def pose_sigmas(t: MeasurementTable, orientation: Orientation) -> PoseSigmas:
    """The ``sigma`` / ``sigma_rot`` columns, else the per-axis ones (``sigma_x ..``:
    per instrument axis; ``sigma_rx ..``: per angle column of ``orientation``,
    propagated to rotations by :func:`angle_axes`; a note says so), else None.  Per-angle
    ones with quaternion columns are one error line (a quaternion has no angles)."""
    out: list[Array | None] = []
    axes_matrix: Array | None = None
    for single, axes in (("sigma", AXIS_SIGMAS[0]), ("sigma_rot", AXIS_SIGMAS[1])):
        per_axis = [a for a in axes if a in t.values]
        if single in t.values and per_axis:
            raise t.error(f"both {t.columns[single]} and per-axis {t.columns[per_axis[0]]}: "
                          "give one or the other")
        if per_axis and len(per_axis) != 3:
            missing = [a for a in axes if a not in t.values]
            raise t.error(f"per-axis standard deviations need all three columns; "
                          f"missing {missing[0]!r}")
        s = t.values.get(single)
        if s is None and per_axis:
            s = np.stack([np.asarray(t.values[a], dtype=float) for a in axes], axis=1)
            names = ", ".join(t.columns[a] for a in axes)
            if single == "sigma":
                t.notes.append(f"{names}: weighted per instrument axis (1/sigma^2 each)")
            elif orientation.kind == "quaternion":
                raise t.error(f"{names}: per-angle standard deviations need angle columns "
                              "(rpy, euler, rotvec), not a quaternion; give sigma_rot")
            else:
                axes_matrix = angle_axes(orientation, {c: t.values[c]
                                                       for c in ("rx", "ry", "rz")})
                t.notes.append(f"{names}: per-angle standard deviations of "
                               f"{orientation.text}, propagated to rotations about the "
                               "instrument axes (covariance E diag(s^2) E^T)")
        out.append(s)
    return PoseSigmas(out[0], out[1], axes_matrix)
