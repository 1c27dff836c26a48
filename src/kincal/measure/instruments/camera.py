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

File columns: fixed ``station, u, v, fx, fy, cx, cy, sigma``; hand-held ``target_x/y/z``
instead of ``station`` (tag ``mount=hand``).  Simulator: :func:`simulate_camera`.
The module registers the ``camera`` instrument (:mod:`kincal.measure.registry`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.base import MeasurementModel, ParamSpec
from kincal.measure.files import Field, read_header
from kincal.measure.instruments.common import (
    MARKER_MODES,
    as_q,
    as_sigma,
    check_shapes,
    concat_specs,
    frame_spec,
    kabsch,
    rotation_to_rpy_frame,
    station_columns,
    station_poses_from_directions,
    to_local,
    to_world,
)
from kincal.measure.instruments.csvio import (
    block_name,
    block_tags,
    build_block,
    label_column,
    one_block,
    per_group,
    read_block_table,
    stack_columns,
    write_block_table,
)
from kincal.measure.instruments.placement import (
    POINT_OPTIONS,
    labels_for,
    look_at,
    marker_truth,
    stated_sigma,
    stations_around,
    tool_points,
    truth_values,
    workspace,
)
from kincal.measure.instruments.pointblock import PointBlock, refine_block
from kincal.measure.registry import Instrument, register
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot
from kincal.spatial import matrix_from_frame

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

    SIGMA_UNIT = "px"

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


class PixelRowsMeasurement(MeasurementModel):
    """Rows of known points, each seen at a pixel by a pinhole camera (the shared part of
    the camera-on-the-hand and board-on-the-flange blocks).

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        points: (N, 3) the observed point of each row, in the frame the block's
            parameters hold (target or board) [m].
        uv: (N, 2) measured (undistorted) pixel coordinates [px].
        sigma: standard deviation of each coordinate [px], scalar or (N,).
        intrinsics: ``(fx, fy, cx, cy)`` [px].
    """

    SIGMA_UNIT = "px"
    #: How the points are called in a shape error.
    POINTS = "points"

    def __init__(self, name: str, q: ArrayLike, points: ArrayLike, uv: ArrayLike,
                 sigma: ArrayLike, intrinsics: Sequence[float]) -> None:
        self.name = name
        self.q = as_q(q)
        N = self.q.shape[0]
        self.s = np.asarray(points, dtype=float).reshape(-1, 3)
        self.obs = np.asarray(uv, dtype=float).reshape(-1, 2)
        check_shapes("camera", name, N, **{self.POINTS: self.s, "uv": self.obs})
        self.sigma = as_sigma(sigma, N, name)
        self.intrinsics = tuple(float(v) for v in intrinsics)
        self.K = np.broadcast_to(check_intrinsics(np.array(self.intrinsics), name), (N, 4))

    def measurement_sigma(self) -> Array:
        """Stated standard deviation of each image coordinate [px]: (N,)."""
        return self.sigma


class HandCameraMeasurement(PixelRowsMeasurement):
    """Pixel coordinates of known target points seen by a camera on the flange.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        target_points: (N, 3) the observed point of each row, in the target frame [m].
        uv: (N, 2) measured pixel coordinates [px].
        sigma: standard deviation of each coordinate [px], scalar or (N,).
        intrinsics: ``(fx, fy, cx, cy)`` [px] of the camera (the robot's tool frame).
    """

    POINTS = "target_points"

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


# ---------------------------------------------------------------------------- file columns
INTRINSICS = ("fx", "fy", "cx", "cy")


CAMERA_FIELDS = (Field("u", "pixel", "u (image column)"), Field("v", "pixel", "v (image row)"),
                 *(Field(k, "pixel", f"{k} (intrinsics)") for k in INTRINSICS),
                 Field("sigma", "pixel", "sigma (standard deviation of u and v)"))


HAND_FIELDS = CAMERA_FIELDS + tuple(Field(f"target_{c}", "length", f"target_{c} (target "
                                          "point in the target frame)") for c in "xyz")


def write_camera(blocks: Sequence[Any], path: str | Path,
                 units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """Fixed: ``station, u, v, fx, fy, cx, cy, sigma``; hand-held: ``target_x/y/z`` instead
    of ``station``."""
    b = one_block(blocks, "camera")
    K = np.asarray(b.K, dtype=float)
    if isinstance(b, HandCameraMeasurement):
        cols: list[tuple[str, Any, str]] = [(f"target_{c}", b.s[:, i], "length")
                                            for i, c in enumerate("xyz")]
        tags = block_tags("camera", b, mount="hand")
    else:
        cols = [("station", b.station_labels, "text")]
        tags = block_tags("camera", b, mount="fixed", marker=b.marker)
    cols += [("u", b.obs[:, 0], "pixel"), ("v", b.obs[:, 1], "pixel")]
    cols += [(k, K[:, i], "pixel") for i, k in enumerate(INTRINSICS)]
    cols.append(("sigma", b.sigma, "pixel"))
    write_block_table(path, tags, b.q, cols, units, robot,
                      ["u = fx x/z + cx, v = fy y/z + cy (undistorted pixels; camera z "
                       "forward)"])


def read_camera(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``camera`` CSV into one block (SI units); a bad file raises one line
    naming the file and the line (:class:`~kincal.errors.MeasurementFileError`)."""
    mount = read_header(path)[0].get("mount", "fixed")
    hand = mount == "hand"
    fields = HAND_FIELDS if hand else CAMERA_FIELDS
    req = ("u", "v", *INTRINSICS, "sigma") + (("target_x", "target_y", "target_z")
                                               if hand else ())
    tab = read_block_table(path, robot, "camera", fields, req,
                           {} if hand else {"station": None}, units, ignore)
    tab.option("mount", "fixed", ("fixed", "hand"))
    uv = stack_columns(tab.values, ("u", "v"))
    K = stack_columns(tab.values, INTRINSICS)
    if np.any(K[:, :2] <= 0):
        r = int(np.argmax(np.any(K[:, :2] <= 0, axis=1)))
        raise tab.error(r, "focal lengths fx, fy must be positive")
    if hand:
        Kc = per_group(tab, np.zeros(len(K), dtype=np.intp), K, "camera intrinsics")[0]
        return [build_block(tab, lambda: HandCameraMeasurement(
            block_name(tab, name, "camera"), tab.q,
            stack_columns(tab.values, ("target_x", "target_y", "target_z")),
            uv, tab.values["sigma"], Kc))]
    stations, idx = label_column(tab, "station", "camera")
    Kg = per_group(tab, idx, K, "camera intrinsics")
    marker = tab.option("marker", "own", MARKER_MODES)
    return [build_block(tab, lambda: CameraMeasurement(
        block_name(tab, name, "camera"), tab.q, tab.text["station"], uv, tab.values["sigma"],
        {s: tuple(Kg[g]) for g, s in enumerate(stations)}, marker))]


# ---------------------------------------------------------------------------- simulation
def _visible(x: Array, K: Array, size: tuple[float, float]) -> tuple[Array, NDArray[np.bool_]]:
    uv = project(np.where(x[:, 2:3] > 1e-9, x, 1.0), K, False)[0]
    ok = (x[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] <= size[0]) & (uv[:, 1] >= 0) \
        & (uv[:, 1] <= size[1])
    return uv, ok


def simulate_camera(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                    mount: str = "fixed", cameras: int = 2, focal_px: float = 2000.0,
                    width_px: int = 2048, height_px: int = 1536, grid: int = 5,
                    spacing_mm: float = 40.0, marker: str = "own", name: str = "camera",
                    margin: float = 0.05, truth: Mapping[str, float] | None = None
                    ) -> tuple[list[Any], dict[str, float]]:
    """Pixel coordinates [px] seen by fixed cameras or by a camera on the flange.

    ``mount="fixed"``: ``cameras`` cameras 2-3 m from the workspace look at its centre;
    every pose whose marker falls inside the image gives one row per camera.
    ``mount="hand"``: the camera is the robot's tool frame; a ``grid x grid`` target of
    ``spacing_mm`` pitch stands 1 m beside the workspace facing it; poses are kept when
    at least 4 target points are seen, one row per visible point.
    """
    K = (float(focal_px), float(focal_px), float(width_px) / 2.0, float(height_px) / 2.0)
    size = (float(width_px), float(height_px))
    sigma = stated_sigma(noise, "px")
    if mount == "hand":
        return _simulate_hand(true_robot, rng, n_poses, noise, K, size, int(grid),
                              float(spacing_mm) * 1e-3, name, margin, truth, sigma)
    if mount != "fixed":
        raise MeasurementFileError(f"option mount={mount!r}: use 'fixed' or 'hand'")
    labels = labels_for(cameras, "c")
    C = len(labels)
    probe = CameraMeasurement(name, np.zeros((C, true_robot.n)), labels, np.zeros((C, 2)),
                              sigma, {s: K for s in labels}, marker=marker)
    names = probe.parameters().names
    if truth is not None:
        values = truth_values(truth, names)
    else:
        centre, _ = workspace(true_robot, rng, margin)
        eyes = stations_around(rng, centre, C, (2.0, 3.0), (0.3, 1.0))
        frames = [look_at(e, centre + rng.normal(0, 0.05, 3)) for e in eyes]
        values = np.concatenate(frames + ([marker_truth(rng)] if marker == "own" else []))
    m = values[-3:] if marker == "own" else None
    q = random_configurations(true_robot, 3 * n_poses, rng, margin)
    qq = np.repeat(q, C, axis=0)
    idx = np.tile(np.arange(C), len(q))
    x = to_local(values[: 6 * C].reshape(C, 6), idx, tool_points(true_robot, qq, m), False)[0]
    uv, ok = _visible(x, np.broadcast_to(K, (len(qq), 4)), size)
    pose_ok = np.all(ok.reshape(len(q), C), axis=1)
    keep_pose = np.flatnonzero(pose_ok)[:n_poses]
    rows = (keep_pose[:, None] * C + np.arange(C)).reshape(-1)
    if len(keep_pose) < min(n_poses, 6):
        raise KincalError("the simulated cameras see too few poses; enlarge the image")
    uv = uv[rows] + (rng.normal(0.0, noise, (len(rows), 2)) if noise > 0 else 0.0)
    block = CameraMeasurement(name, qq[rows], [labels[i] for i in idx[rows]], uv, sigma,
                              {s: K for s in labels}, marker=marker)
    return [block], dict(zip(names, values.tolist(), strict=True))


def target_grid(grid: int, spacing: float) -> Array:
    """``grid x grid`` points [m] on the target plane z = 0, centred."""
    g = (np.arange(grid) - (grid - 1) / 2.0) * spacing
    X, Y = np.meshgrid(g, g, indexing="ij")
    return np.column_stack([X.reshape(-1), Y.reshape(-1), np.zeros(grid * grid)])


def _simulate_hand(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                   K: tuple[float, ...], size: tuple[float, float], grid: int, spacing: float,
                   name: str, margin: float, truth: Mapping[str, float] | None, sigma: float
                   ) -> tuple[list[Any], dict[str, float]]:
    pts = target_grid(grid, spacing)
    probe = HandCameraMeasurement(name, np.zeros((1, true_robot.n)), pts[:1], np.zeros((1, 2)),
                                  sigma, K)
    names = probe.parameters().names
    if truth is not None:
        values = truth_values(truth, names)
    else:
        centre, _ = workspace(true_robot, rng, margin)
        where = stations_around(rng, centre, 1, (0.9, 1.1), (-0.2, 0.2))[0]
        # target z axis towards the workspace (the camera looks at its front)
        f = look_at(where, centre)
        R = matrix_from_frame(f)[:3, :3] @ np.diag([1.0, -1.0, -1.0])     # flip z to face back
        values = rotation_to_rpy_frame(R, where)
    w = to_world(values, pts, False)[0]
    normal = matrix_from_frame(values)[:3, 2]
    qs, pose_rows = [], []
    got = 0
    for _ in range(200):                     # batches of candidate poses until enough
        q = random_configurations(true_robot, 4000, rng, margin)
        T = true_robot.fk(q)
        x = np.einsum("nji,nkj->nki", T[:, :3, :3], w[None] - T[:, None, :3, 3])
        N, P = x.shape[:2]
        uv, ok = _visible(x.reshape(-1, 3), np.broadcast_to(K, (N * P, 4)), size)
        front = (T[:, :3, 3] - w.mean(0)) @ normal < 0      # camera on the target's face
        ok = ok.reshape(N, P) & front[:, None] & (x[:, :, 2] < 1.5)
        good = np.flatnonzero(ok.sum(1) >= 4)[: n_poses - got]
        rows, cols = np.nonzero(ok[good])                 # visible (pose, point) pairs
        qs.append(q[good][rows])
        pose_rows.append((uv.reshape(N, P, 2)[good][rows, cols], pts[cols]))
        got += len(good)
        if got >= n_poses:
            break
    if got < min(n_poses, 6):
        raise KincalError("the simulated hand-held camera sees the target from too few poses")
    qq = np.vstack(qs)
    uv = np.vstack([u for u, _ in pose_rows])
    s = np.vstack([p for _, p in pose_rows])
    if noise > 0:
        uv = uv + rng.normal(0.0, noise, uv.shape)
    block = HandCameraMeasurement(name, qq, s, uv, sigma, K)
    return [block], dict(zip(names, values.tolist(), strict=True))


register(Instrument(
    name="camera",
    description="pixel coordinates from calibrated pinhole cameras (fixed, or on the hand)",
    simulate=simulate_camera, write=write_camera, read=read_camera,
    options={"mount": ("fixed", "'fixed': cameras watch a tool marker; 'hand': the camera "
                                "is the tool frame and watches a fixed target"),
             "cameras": (2, "number of fixed cameras"),
             "focal_px": (2000.0, "focal length [px]"),
             "width_px": (2048, "image width [px]"), "height_px": (1536, "image height [px]"),
             "grid": (5, "hand-held: target points per side"),
             "spacing_mm": (40.0, "hand-held: target pitch [mm]"),
             "name": ("camera", "block name (prefix of its parameters)"), **POINT_OPTIONS},
    noise_unit="px"))
