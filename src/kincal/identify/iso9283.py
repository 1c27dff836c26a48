"""ISO 9283 acceptance figures: pose accuracy and repeatability, distance accuracy.

**Test cube and positions** (ISO 9283, 6.2-6.3).  A cube of edge ``L`` in the working
space; the test plane is its diagonal plane through the bottom-front edge and the
top-back edge (corners ``C1 = (-h, -h, -h)``, ``C2 = (-h, +h, -h)``, ``C7 = (+h, +h,
+h)``, ``C8 = (+h, -h, +h)`` about the centre, ``h = L / 2``, cube axes along the base
frame's).  ``P1`` is the centre; ``P2 ... P5`` lie on the plane's diagonals at 10 % of
the diagonal's length from the corners ``C1, C2, C7, C8``.  The cycle visits ``P1, P5,
P4, P3, P2`` and is repeated ``n`` times (30 in the standard); the orientation is the
same at every position.

**Characteristics** per position ``j`` from its ``n`` attained poses (7.2, 7.2.3):

* pose accuracy ``AP = sqrt((x̄ - x_c)^2 + (ȳ - y_c)^2 + (z̄ - z_c)^2)`` [m] (x̄ the mean
  of the attained positions, ``x_c`` the commanded one) and orientation accuracy
  ``AP_a = ā - a_c`` (and b, c) [rad];
* pose repeatability ``RP = l̄ + 3 S_l`` [m] with ``l_i = |p_i - p̄|``, ``l̄`` their mean and
  ``S_l = sqrt(sum (l_i - l̄)^2 / (n - 1))``; orientation ``RP_a = +-3 S_a``;
* distance accuracy between two positions (``P2`` and ``P4``), ``AD = D̄ - D_c`` with
  ``D_i = |p_i(P2) - p_i(P4)|`` over the cycles and ``D_c`` the commanded distance, and
  distance repeatability ``RD = +-3 S_D``.

Orientation angles are the attained rotations relative to the commanded one, as a
rotation vector (small angles: about x, y, z of the base frame).  Units: m, rad.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.spatial import log_so3

if TYPE_CHECKING:
    from kincal.measure.instruments.position import PositionMeasurement
    from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["CYCLE", "PositionFigures", "cube_positions", "distance_figures",
           "group_positions", "pose_figures"]

#: The order in which a cycle visits the positions.
CYCLE = ("P1", "P5", "P4", "P3", "P2")


def cube_positions(center: ArrayLike, size: float) -> dict[str, Array]:
    """``{P1 ... P5: (3,)}`` [m] of the test cube centred at ``center`` with edge ``size``."""
    c = np.asarray(center, dtype=float).reshape(3)
    if not size > 0:
        raise KincalError(f"the ISO 9283 cube needs a positive edge, got {size}")
    h = size / 2.0
    C1, C2 = np.array([-h, -h, -h]), np.array([-h, h, -h])
    C7, C8 = np.array([h, h, h]), np.array([h, -h, h])
    # diagonals of the plane: C1-C7 and C2-C8; 10 % of a diagonal's length from each corner
    P = {"P1": c.copy()}
    for name, corner, other in (("P2", C1, C7), ("P3", C2, C8), ("P4", C7, C1),
                                ("P5", C8, C2)):
        P[name] = c + corner + 0.1 * (other - corner)
    return P


@dataclass(frozen=True)
class PositionFigures:
    """ISO 9283 pose characteristics of one position.

    Attributes:
        name: position name (``P1`` ...).
        n: cycles.
        AP: pose (position) accuracy [m]; NaN without a commanded position.
        AP_abc: orientation accuracy about x, y, z [rad] (NaN for position data).
        RP: position repeatability ``l̄ + 3 S_l`` [m].
        RP_abc: orientation repeatability ``3 S`` about x, y, z [rad].
        mean_offset: (3,) ``p̄ - p_c`` [m].
    """

    name: str
    n: int
    AP: float
    AP_abc: Array
    RP: float
    RP_abc: Array
    mean_offset: Array

    def to_dict(self) -> dict[str, object]:
        return {"position": self.name, "cycles": self.n, "AP_m": self.AP,
                "AP_abc_rad": self.AP_abc.tolist(), "RP_m": self.RP,
                "RP_abc_rad": self.RP_abc.tolist(), "mean_offset_m": self.mean_offset.tolist()}


def pose_figures(name: str, attained: ArrayLike, commanded: ArrayLike | None = None
                 ) -> PositionFigures:
    """ISO 9283 AP and RP of one position from its attained positions (n, 3) or poses
    (n, 4, 4) [m] and the commanded position (3,) / pose (4, 4) (None: RP only)."""
    A = np.asarray(attained, dtype=float)
    poses = A.ndim == 3
    p = A[:, :3, 3] if poses else A
    n = len(p)
    if n < 2:
        raise KincalError(f"position {name}: ISO 9283 repeatability needs at least 2 cycles, "
                          f"got {n}")
    pbar = p.mean(axis=0)
    l = np.linalg.norm(p - pbar, axis=1)
    RP = float(l.mean() + 3.0 * l.std(ddof=1))
    AP, offset = np.nan, np.full(3, np.nan)
    AP_abc, RP_abc = np.full(3, np.nan), np.full(3, np.nan)
    if commanded is not None:
        C = np.asarray(commanded, dtype=float)
        pc = C[:3, 3] if C.shape == (4, 4) else C.reshape(3)
        offset = pbar - pc
        AP = float(np.linalg.norm(offset))
    if poses:
        Rref = (np.asarray(commanded, dtype=float)[:3, :3] if commanded is not None and
                np.asarray(commanded).shape == (4, 4) else A[0, :3, :3])
        w = log_so3(A[:, :3, :3] @ Rref.T)              # attained relative to commanded
        RP_abc = 3.0 * w.std(axis=0, ddof=1)
        if commanded is not None and np.asarray(commanded).shape == (4, 4):
            AP_abc = w.mean(axis=0)
    return PositionFigures(name, n, AP, AP_abc, RP, RP_abc, offset)


def distance_figures(attained_a: ArrayLike, attained_b: ArrayLike,
                     commanded_a: ArrayLike | None = None, commanded_b: ArrayLike | None = None
                     ) -> dict[str, float]:
    """Distance accuracy ``AD = D̄ - D_c`` and repeatability ``RD = 3 S_D`` [m] between two
    positions measured in the same cycles (n, 3) each."""
    a, b = np.asarray(attained_a, dtype=float), np.asarray(attained_b, dtype=float)
    if a.shape != b.shape:
        raise KincalError("distance figures need the same cycles at both positions")
    D = np.linalg.norm(a - b, axis=1)
    out = {"D_mean_m": float(D.mean()), "RD_m": float(3.0 * D.std(ddof=1))}
    if commanded_a is not None and commanded_b is not None:
        Dc = float(np.linalg.norm(np.asarray(commanded_a, float) - np.asarray(commanded_b,
                                                                                float)))
        out.update({"D_commanded_m": Dc, "AD_m": float(D.mean() - Dc)})
    return out


def group_positions(q: ArrayLike, tol: float = 1e-3, names: Sequence[str] | None = None
                    ) -> list[str]:
    """A position name per row: rows whose joint values agree within ``tol`` [rad / m]
    are one position (encoders read a revisited pose slightly differently).  Names in
    order of first appearance; five positions are taken to be in the ISO cycle order
    (``P1, P5, P4, P3, P2``), any other number are called ``P1, P2, ...``."""
    Q = np.atleast_2d(np.asarray(q, dtype=float))
    centers: list[Array] = []
    index = []
    for row in Q:
        for k, c in enumerate(centers):
            if np.max(np.abs(row - c)) <= tol:
                index.append(k)
                break
        else:
            centers.append(row)
            index.append(len(centers) - 1)
    labels = list(names) if names is not None else (
        list(CYCLE) if len(centers) == 5 else [f"P{k + 1}" for k in range(len(centers))])
    return [labels[k] for k in index]


def block_figures(robot: Robot, block: PositionMeasurement, extra: ArrayLike,
                  labels: Sequence[str] | None = None
                  ) -> tuple[list[PositionFigures], dict[str, float] | None]:
    """ISO 9283 figures of a position-measurement block: attained = the measured points,
    commanded = the robot model's prediction at the joint readings (mean per position),
    both in the instrument frame (``extra``: the block's frame and marker).

    Returns the per-position figures (in order of first appearance) and the distance
    figures between ``P2`` and ``P4`` when both were measured in the same number of cycles.
    """
    y = np.asarray(block.positions, dtype=float)
    if y.ndim == 3:
        y = y[:, 0]
    pred = np.asarray(block.predict(robot, extra), dtype=float)[:, 0]
    names = list(labels) if labels is not None else group_positions(block.q)
    order = list(dict.fromkeys(names))
    figs = []
    for name in order:
        rows = [i for i, n in enumerate(names) if n == name]
        figs.append(pose_figures(name, y[rows], pred[rows].mean(axis=0)))
    dist = None
    if "P2" in order and "P4" in order:
        r2 = [i for i, n in enumerate(names) if n == "P2"]
        r4 = [i for i, n in enumerate(names) if n == "P4"]
        if len(r2) == len(r4) and len(r2) >= 2:
            dist = distance_figures(y[r2], y[r4], pred[r2].mean(axis=0), pred[r4].mean(axis=0))
    return figs, dist
