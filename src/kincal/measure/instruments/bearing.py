"""Bearing instruments: a theodolite's two angles to the tool point (triangulation).

Each station ``k`` has a pose ``T_k = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` in the world
(its z axis is the instrument's vertical axis, its x axis the zero of the horizontal
circle).  The tool point in the station frame is ``x = R_k^T (p(q) - t_k)`` and the
measurement equations are [rad]::

    az = atan2(x_2, x_1)                    horizontal angle, counter-clockwise about z
    el = atan2(x_3, sqrt(x_1^2 + x_2^2))    elevation above the horizontal plane

(a theodolite reading clockwise horizontal directions ``Hz`` and zenith angles ``V``
gives ``az = -Hz``, ``el = pi/2 - V``).  Residuals are ``(az_pred - az_obs) / sigma``,
wrapped to (-pi, pi], and ``(el_pred - el_obs) / sigma``.  Jacobians, with
``h = sqrt(x_1^2 + x_2^2)``, ``r = |x|``::

    d az/dx = (-x_2, x_1, 0) / h^2
    d el/dx = (-x_1 x_3 / h, -x_2 x_3 / h, h) / r^2

chained with ``dx/dp = R_k^T`` and ``dx/d(station)`` from :func:`.common.to_local`.

Parameters: ``{name}.{station}.x, y, z, rz, ry, rx`` [m, rad] per station, then the marker
``{name}.marker.x, y, z`` (``marker="own"``).

What angles cannot see: angles do not change when the whole scene is scaled about a
station, so bearings alone never fix the scale (one robot length or the station
baseline must be known, or a range instrument fused); one station also cannot separate
its own pose from the robot's base frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.measure.base import ParamSpec
from kincal.measure.instruments.common import (
    concat_specs,
    frame_spec,
    station_columns,
    station_poses_from_directions,
    to_local,
)
from kincal.measure.instruments.pointblock import PointBlock
from kincal.robots.chain import Robot
from kincal.spatial import wrap_angle

Array = NDArray[np.float64]


wrap = wrap_angle   # (-pi, pi]


def bearing_angles(x: Array, jacobian: bool) -> tuple[Array, Array | None]:
    """``(az, el)`` (N, 2) [rad] of points ``x`` (N, 3) in a station frame, and d/dx (N, 2, 3)."""
    h2 = x[:, 0] ** 2 + x[:, 1] ** 2
    h = np.sqrt(h2)
    ang = np.column_stack([np.arctan2(x[:, 1], x[:, 0]), np.arctan2(x[:, 2], h)])
    if not jacobian:
        return ang, None
    r2 = h2 + x[:, 2] ** 2
    D = np.zeros((x.shape[0], 2, 3))
    D[:, 0, 0] = -x[:, 1] / h2
    D[:, 0, 1] = x[:, 0] / h2
    D[:, 1, 0] = -x[:, 0] * x[:, 2] / (h * r2)
    D[:, 1, 1] = -x[:, 1] * x[:, 2] / (h * r2)
    D[:, 1, 2] = h / r2
    return ang, D


def bearing_directions(ang: Array) -> Array:
    """Unit directions (N, 3) of ``(az, el)`` (N, 2) in the station frame."""
    ce = np.cos(ang[:, 1])
    return np.column_stack([ce * np.cos(ang[:, 0]), ce * np.sin(ang[:, 0]), np.sin(ang[:, 1])])


class BearingMeasurement(PointBlock):
    """Horizontal and vertical angles from one or more theodolite stations.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        station: (N,) station label of each reading.
        angles: (N, 2) measured ``(az, el)`` [rad].
        sigma: standard deviation of each angle [rad], scalar or (N,).
        marker: ``"own"`` or ``"tool"`` (see :mod:`.common`).
    """

    def __init__(self, name: str, q: ArrayLike, station: Sequence[str], angles: ArrayLike,
                 sigma: ArrayLike, marker: str = "own") -> None:
        N = self._init_rows("bearing", name, q, angles, 2, "angles", sigma, marker)
        self._init_stations(station, "station", N)

    def own_parameters(self) -> ParamSpec:
        return concat_specs([frame_spec(f"{self.name}.{s}") for s in self.stations])

    def difference(self, pred: Array) -> Array:
        d = pred - self.obs
        d[:, 0] = wrap(d[:, 0])
        return d

    def observe(self, p: Array, own: Array, jacobian: bool
                ) -> tuple[Array, Array | None, Array | None]:
        frames = own.reshape(-1, 6)
        x, dxdp, dxds = to_local(frames, self.station_index, p, jacobian)
        ang, D = bearing_angles(x, jacobian)
        if not jacobian:
            return ang, None, None
        assert D is not None and dxdp is not None and dxds is not None
        return ang, D @ dxdp, station_columns(self.station_index, D @ dxds, own.size)

    def own_guess(self, robot: Robot, p: Array) -> Array:
        """Each station's pose by the linear direction DLT (:func:`.common.direction_pose`)."""
        return station_poses_from_directions(self.stations, self.station_index,
                                             bearing_directions(self.obs), p, "station",
                                             self.name)

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0].reshape(-1, 2)
        return {"angle_rad": np.hypot(r[:, 0], r[:, 1]) * self.sigma}
