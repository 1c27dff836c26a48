"""Cameras: pixel coordinates of points seen by calibrated pinhole cameras.

Intrinsics are given (calibrated beforehand) per camera: focal lengths ``fx, fy`` and
principal point ``cx, cy`` [px]; image coordinates must be undistorted.  A point ``x``
in the camera frame (z along the optical axis, x to the right, y down) projects to::

    u = fx x_1 / x_3 + cx,      v = fy x_2 / x_3 + cy        [px]

with ``du/dx = (fx / x_3, 0, -fx x_1 / x_3^2)``, ``dv/dx = (0, fy / x_3, -fy x_2 / x_3^2)``.
Residuals are ``(u_pred - u_obs) / sigma`` and ``(v_pred - v_obs) / sigma`` [1].

Two variants:

* :class:`CameraMeasurement` -- fixed cameras watch the tool point: ``x = R_c^T (p(q) - t_c)``
  with the camera pose ``{name}.{camera}.x, y, z, rz, ry, rx`` [m, rad] a parameter per
  camera, then the marker ``{name}.marker.x, y, z``.  Like every angle instrument a camera
  cannot see the scale of the scene (scaling about the camera centre leaves the image
  unchanged): fuse a range instrument or fix a length.
* :class:`HandCameraMeasurement` -- a camera on the flange looks at a fixed target whose
  points ``s_j`` are known in the target's own frame (a calibrated plate: this fixes the
  scale).  The camera frame *is* the robot's tool frame (put the nominal hand-eye pose
  in the robot's ``tool.*`` parameters; they are estimated with the robot), the target
  pose ``{name}.target.x, y, z, rz, ry, rx`` is the block's parameter::

      w = R_t s_j + t_t,       x = R_e(q)^T (w - p_e(q))

  and ``dx/d(robot) = R_e^T ((w - p_e) x omega - v)`` for the parameter twists ``[v; omega]``.
  The robot's base frame and the target pose are only seen together (six dependent
  directions): fix one of them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import MeasurementModel, ParamSpec
from kincal.measure.instruments.common import (
    as_q,
    as_sigma,
    check_shapes,
    concat_specs,
    frame_spec,
    rotation_to_rpy_frame,
    station_columns,
    station_poses_from_directions,
    to_local,
    to_world,
)
from kincal.measure.instruments.pointblock import PointBlock, refine_block
from kincal.measure.models import kabsch
from kincal.robots.chain import Robot

Array = NDArray[np.float64]


def project(x: Array, K: Array, jacobian: bool) -> tuple[Array, Array | None]:
    """Pinhole projection of camera-frame points ``x`` (N, 3) with per-row intrinsics
    ``K`` (N, 4) = ``fx, fy, cx, cy`` [px]: ``uv`` (N, 2) and ``d uv/dx`` (N, 2, 3)."""
    z = x[:, 2]
    uv = np.column_stack([K[:, 0] * x[:, 0] / z + K[:, 2], K[:, 1] * x[:, 1] / z + K[:, 3]])
    if not jacobian:
        return uv, None
    D = np.zeros((x.shape[0], 2, 3))
    D[:, 0, 0] = K[:, 0] / z
    D[:, 0, 2] = -K[:, 0] * x[:, 0] / z**2
    D[:, 1, 1] = K[:, 1] / z
    D[:, 1, 2] = -K[:, 1] * x[:, 1] / z**2
    return uv, D


def pixel_directions(uv: Array, K: Array) -> Array:
    """Viewing directions ``((u - cx)/fx, (v - cy)/fy, 1)`` (N, 3) in the camera frame."""
    return np.column_stack([(uv[:, 0] - K[:, 2]) / K[:, 0], (uv[:, 1] - K[:, 3]) / K[:, 1],
                            np.ones(uv.shape[0])])


def check_intrinsics(K: Array, name: str) -> Array:
    K = np.asarray(K, dtype=float).reshape(-1, 4)
    if not np.all(np.isfinite(K)) or np.any(K[:, :2] <= 0):
        raise KincalError(f"block {name!r}: camera focal lengths fx, fy must be positive")
    return K


class CameraMeasurement(PointBlock):
    """Pixel coordinates of the tool marker seen by one or more fixed cameras.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        station: (N,) camera label of each reading.
        uv: (N, 2) measured pixel coordinates [px].
        sigma: standard deviation of each coordinate [px], scalar or (N,).
        intrinsics: ``{camera: (fx, fy, cx, cy)}`` [px].
        marker: ``"own"`` or ``"tool"`` (see :mod:`.common`).
    """

    row_fields = PointBlock.row_fields + ("K",)

    def __init__(self, name: str, q: ArrayLike, station: Sequence[str], uv: ArrayLike,
                 sigma: ArrayLike, intrinsics: dict[str, Sequence[float]],
                 marker: str = "own") -> None:
        N = self._init_rows("camera", name, q, uv, 2, "uv", sigma, marker)
        self._init_stations(station, "camera", N)
        missing = [s for s in self.stations if s not in intrinsics]
        if missing:
            raise KincalError(f"block {name!r}: no intrinsics for camera {missing[0]!r}")
        self.intrinsics = {s: tuple(float(v) for v in intrinsics[s]) for s in self.stations}
        self.K = check_intrinsics(np.array([self.intrinsics[s] for s in self.stations]),
                                  name)[self.station_index]

    def own_parameters(self) -> ParamSpec:
        return concat_specs([frame_spec(f"{self.name}.{s}") for s in self.stations])

    def observe(self, p: Array, own: Array, jacobian: bool
                ) -> tuple[Array, Array | None, Array | None]:
        x, dxdp, dxds = to_local(own.reshape(-1, 6), self.station_index, p, jacobian)
        uv, D = project(x, self.K, jacobian)
        if not jacobian:
            return uv, None, None
        assert D is not None and dxdp is not None and dxds is not None
        return uv, D @ dxdp, station_columns(self.station_index, D @ dxds, own.size)

    def own_guess(self, robot: Robot, p: Array) -> Array:
        """Each camera's pose by the linear DLT on the viewing directions."""
        return station_poses_from_directions(self.stations, self.station_index,
                                             pixel_directions(self.obs, self.K), p, "camera",
                                             self.name)

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0].reshape(-1, 2)
        return {"image_px": np.hypot(r[:, 0], r[:, 1]) * self.sigma}


class HandCameraMeasurement(MeasurementModel):
    """Pixel coordinates of known target points seen by a camera on the flange.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        target_points: (N, 3) the observed point of each row, in the target frame [m].
        uv: (N, 2) measured pixel coordinates [px].
        sigma: standard deviation of each coordinate [px], scalar or (N,).
        intrinsics: ``(fx, fy, cx, cy)`` [px] of the camera (the robot's tool frame).
    """

    def __init__(self, name: str, q: ArrayLike, target_points: ArrayLike, uv: ArrayLike,
                 sigma: ArrayLike, intrinsics: Sequence[float]) -> None:
        self.name = name
        self.q = as_q(q)
        N = self.q.shape[0]
        self.s = np.asarray(target_points, dtype=float).reshape(-1, 3)
        self.obs = np.asarray(uv, dtype=float).reshape(-1, 2)
        check_shapes("camera", name, N, target_points=self.s, uv=self.obs)
        self.sigma = as_sigma(sigma, N, name)
        self.intrinsics = tuple(float(v) for v in intrinsics)
        self.K = np.broadcast_to(check_intrinsics(np.array(self.intrinsics), name), (N, 4))

    def measurement_sigma(self) -> Array:
        """Stated standard deviation of each image coordinate [px]: (N,)."""
        return self.sigma

    def parameters(self) -> ParamSpec:
        return frame_spec(f"{self.name}.target", role="target")

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        extra = np.asarray(extra, dtype=float)
        T, _, Jp = robot.fk_with_jacobians(self.q, joints=False, params=jacobian)
        Rt = np.swapaxes(T[:, :3, :3], 1, 2)
        w, dw = to_world(extra, self.s, jacobian)
        d = w - T[:, :3, 3]
        x = np.einsum("nij,nj->ni", Rt, d)
        uv, D = project(x, self.K, jacobian)
        r = ((uv - self.obs) / self.sigma[:, None]).reshape(-1)
        if not jacobian:
            return r, None, None
        assert Jp is not None and D is not None and dw is not None
        dx_robot = Rt @ (np.cross(d[:, :, None], Jp[:, 3:], axis=1) - Jp[:, :3])
        scale = self.sigma[:, None, None]
        Jr = (D @ dx_robot / scale).reshape(r.size, -1)
        Je = (D @ Rt @ dw / scale).reshape(r.size, -1)
        return r, Jr, Je

    def residual_owner(self) -> NDArray[np.intp]:
        return np.repeat(np.arange(self.q.shape[0]), 2)

    def initial_guess(self, robot: Robot) -> Array:
        """Triangulate each target point from its viewing rays, register the target.

        With the camera at the robot's nominal tool frame, every row is a ray
        ``c + lambda R_e d``; the rays of one target point meet (least squares) at
        ``w_j = (sum A_i)^-1 sum A_i c_i`` with ``A_i = I - d_i d_i^T``; Kabsch then fits
        the target pose to ``(s_j, w_j)``; Gauss-Newton refines it.
        """
        T = robot.fk(self.q)
        d = np.einsum("nij,nj->ni", T[:, :3, :3], pixel_directions(self.obs, self.K))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        c = T[:, :3, 3]
        pts, idx = np.unique(self.s, axis=0, return_inverse=True)
        idx = idx.reshape(-1)
        A = np.eye(3) - d[:, :, None] * d[:, None, :]
        SA = np.zeros((len(pts), 3, 3))
        Sb = np.zeros((len(pts), 3))
        np.add.at(SA, idx, A)
        np.add.at(Sb, idx, np.einsum("nij,nj->ni", A, c))
        ok = np.linalg.cond(SA) < 1e8
        if np.count_nonzero(ok) < 3:
            raise KincalError(f"block {self.name!r}: fewer than 3 target points are seen from "
                              "two different poses; cannot place the target")
        w = np.linalg.solve(SA[ok], Sb[ok][:, :, None])[:, :, 0]
        R, t = kabsch(pts[ok], w)
        return refine_block(self, robot, rotation_to_rpy_frame(R, t))

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0].reshape(-1, 2)
        return {"image_px": np.hypot(r[:, 0], r[:, 1]) * self.sigma}
