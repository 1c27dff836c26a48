"""Cartesian paths: the pose as a function of a path parameter ``s in [0, 1]``.

A *path* gives the pose as a function of ``s`` with its first two derivatives as
twists ``[dp/ds; omega/ds]`` in the base frame: straight lines and circular arcs, the
orientation interpolated by slerp ``R(s) = R0 exp(s [w]x)``, ``w = log(R0^T R1)``
(body frame), whose angular rate ``omega/ds = R0 w`` is constant.
:mod:`kincal.motion.trajectory` paces a path by a timing law
(:class:`~kincal.motion.trajectory.CartesianMotion`) and re-exports every name.  Units: m, rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.spatial import exp_so3, log_so3

Array = NDArray[np.float64]

__all__ = ["CartesianPath", "LinePath", "ArcPath", "arc_through"]


class CartesianPath(Protocol):
    """A geometric path ``T(s)``, ``s in [0, 1]``."""

    def at(self, s: ArrayLike) -> tuple[Array, Array, Array]:
        """Poses (N, 4, 4) and twists ``dX/ds``, ``d2X/ds2`` (N, 6) in the base frame."""
        ...

    @property
    def length(self) -> float:
        """Length of the position path [m] (for trapezoidal timing)."""
        ...


def _slerp(R0: Array, R1: Array, s: Array) -> tuple[Array, Array]:
    """``R(s) = R0 exp(s [w]x)``, ``w = log(R0^T R1)``; returns R(s) and ``omega/ds = R0 w``."""
    w = log_so3(R0.T @ R1)
    return R0 @ exp_so3(s[:, None] * w), R0 @ w


@dataclass(frozen=True)
class LinePath:
    """Straight segment from pose ``start`` to pose ``end`` (4, 4), orientation by slerp.

    ``p(s) = p0 + s (p1 - p0)``, ``p' = p1 - p0``, ``p'' = 0``; ``omega' = R0 w``, ``alpha = 0``.
    """

    start: Array
    end: Array

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end[:3, 3] - self.start[:3, 3]))

    @property
    def angle(self) -> float:
        """Rotation angle from start to end orientation [rad]."""
        return float(np.linalg.norm(log_so3(self.start[:3, :3].T @ self.end[:3, :3])))

    def at(self, s: ArrayLike) -> tuple[Array, Array, Array]:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        R, w = _slerp(self.start[:3, :3], self.end[:3, :3], s)
        dp = self.end[:3, 3] - self.start[:3, 3]
        T = np.tile(np.eye(4), (s.size, 1, 1))
        T[:, :3, :3] = R
        T[:, :3, 3] = self.start[:3, 3] + s[:, None] * dp
        d1 = np.tile(np.concatenate([dp, w]), (s.size, 1))
        return T, d1, np.zeros_like(d1)


@dataclass(frozen=True)
class ArcPath:
    """Circular arc about ``centre`` and unit ``axis`` through ``angle``, orientation by slerp.

    ``p(s) = c + Rot(n, s theta) (p0 - c)``; ``p' = theta n x (p - c)``;
    ``p'' = theta^2 n x (n x (p - c))``.  The orientation goes from ``R_start`` to
    ``R_end`` by slerp, independently of the arc.
    """

    centre: Array
    axis: Array
    angle: float
    start: Array
    R_end: Array

    @property
    def radius(self) -> float:
        r = self.start[:3, 3] - self.centre
        return float(np.linalg.norm(r - self.axis * (self.axis @ r)))

    @property
    def length(self) -> float:
        return abs(self.angle) * self.radius

    def at(self, s: ArrayLike) -> tuple[Array, Array, Array]:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        n, th = self.axis, self.angle
        r0 = self.start[:3, 3] - self.centre
        r = (exp_so3(np.outer(s * th, n)) @ r0)
        R, w = _slerp(self.start[:3, :3], self.R_end, s)
        T = np.tile(np.eye(4), (s.size, 1, 1))
        T[:, :3, :3] = R
        T[:, :3, 3] = self.centre + r
        v = th * np.cross(n, r)
        a = th**2 * np.cross(n, np.cross(n, r))
        d1 = np.concatenate([v, np.tile(w, (s.size, 1))], 1)
        d2 = np.concatenate([a, np.zeros((s.size, 3))], 1)
        return T, d1, d2


def arc_through(start: ArrayLike, via: ArrayLike, end: ArrayLike) -> ArcPath:
    """The circular arc from pose ``start`` through point ``via`` (3,) to pose ``end``.

    The centre is the circumcentre of the three points; the arc runs from the start
    point through ``via`` to the end point.  Raises for collinear points.
    """
    T0, T1 = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
    a, b, c = T0[:3, 3], np.asarray(via, dtype=float), T1[:3, 3]
    u, v = b - a, c - a
    nrm = np.cross(u, v)
    nn = float(nrm @ nrm)
    if nn < 1e-18 * max(float(u @ u) * float(v @ v), 1e-300):
        raise KincalError("the arc's start, via and end points are collinear (or coincide)")
    centre = a + (np.cross(nrm, u) * (v @ v) + np.cross(v, nrm) * (u @ u)) / (2 * nn)
    axis = nrm / math.sqrt(nn)
    r0, r1 = a - centre, c - centre
    angle = math.atan2(float(axis @ np.cross(r0, r1)), float(r0 @ r1))
    if angle <= 0:
        angle += 2 * math.pi       # through the via point, counter-clockwise about the axis
    return ArcPath(centre, axis, angle, T0, T1[:3, :3])
