"""Virtual instruments: measure a "true" robot the way each instrument would.

Every simulator has the registry signature
``simulate(true_robot, rng, n_poses, noise, **options) -> ([block], truth)``: joint
configurations drawn uniformly inside the limits (:func:`random_configurations`), the
instrument placed plausibly around the robot's workspace, independent Gaussian noise of
standard deviation ``noise`` (m for range/plane/fixture, rad for bearing, px for
camera) on every observation, and ``truth`` = ``{parameter name: true value}`` of the
block's own parameters.  Passing ``truth=`` back re-measures with the same placement
(held-out data).  Range, bearing and camera live here; the contact instruments (plane,
fixture) in :mod:`.simulate_contact`.  Not modelled: occlusion by the robot, refraction,
lens distortion.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.instruments.bearing import BearingMeasurement, bearing_angles
from kincal.measure.instruments.camera import CameraMeasurement, HandCameraMeasurement, project
from kincal.measure.instruments.common import (
    rotation_to_rpy_frame,
    to_local,
    to_world,
)
from kincal.measure.instruments.range import RangeMeasurement
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot
from kincal.spatial import matrix_from_frame

Array = NDArray[np.float64]

#: Stated standard deviation when the simulation is noise-free (the block needs one).
EXACT_SIGMA = {"m": 1e-6, "rad": 1e-6, "px": 0.1}


# ---------------------------------------------------------------------------- helpers
def tool_points(robot: Robot, q: Array, m: Array | None) -> Array:
    """World positions (N, 3) of the marker ``m`` (tool origin when None)."""
    T = robot.fk(q)
    return T[:, :3, 3] + (0.0 if m is None else T[:, :3, :3] @ m)


def workspace(robot: Robot, rng: np.random.Generator, margin: float) -> tuple[Array, float]:
    """Centre (3,) and RMS radius [m] of the tool origin over random configurations."""
    p = tool_points(robot, random_configurations(robot, 400, rng, margin), None)
    c = p.mean(0)
    return c, float(np.sqrt(np.mean(np.sum((p - c) ** 2, axis=1))))


def look_at(eye: Array, target: Array) -> Array:
    """Camera frame ``x y z rz ry rx`` at ``eye`` with z towards ``target`` and y down."""
    up = np.array([0.0, 0.0, 1.0])
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return rotation_to_rpy_frame(np.column_stack([x, np.cross(z, x), z]), eye)


def marker_truth(rng: np.random.Generator) -> Array:
    """A marker within ~0.1 m of the tool origin, mostly along the tool z axis."""
    value: Array = rng.uniform(-0.05, 0.05, 3) + np.array([0.0, 0.0, 0.08])
    return value


def stated_sigma(noise: float, unit: str) -> float:
    return float(noise) if noise > 0 else EXACT_SIGMA[unit]


def truth_values(truth: Mapping[str, float], names: Sequence[str]) -> Array:
    missing = [n for n in names if n not in truth]
    if missing:
        raise MeasurementFileError(f"instrument truth lacks {missing[0]!r}")
    return np.array([float(truth[n]) for n in names])


def _stations_around(rng: np.random.Generator, centre: Array, k: int, dist: tuple[float, float],
                     heights: tuple[float, float]) -> Array:
    """``k`` points around ``centre`` at spread-out headings (k, 3)."""
    az = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(k) / k + rng.uniform(-0.3, 0.3, k)
    r = rng.uniform(*dist, k)
    return centre + np.column_stack([r * np.cos(az), r * np.sin(az), rng.uniform(*heights, k)])


def as_flag(value: Any, option: str) -> bool:
    """A boolean option given as a bool or as text (``true/false/yes/no/1/0``)."""
    if isinstance(value, bool | int | np.integer):
        return bool(value)
    text = str(value).strip().lower()
    if text in ("true", "yes", "1", "on"):
        return True
    if text in ("false", "no", "0", "off"):
        return False
    raise MeasurementFileError(f"option {option}={value!r}: use true or false")


def labels_for(k: int, prefix: str) -> list[str]:
    return [f"{prefix}{i + 1}" for i in range(int(k))]


# ---------------------------------------------------------------------------- range
def simulate_range(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                   stations: int = 4, incremental: bool = False, marker: str = "own",
                   name: str = "range", margin: float = 0.05,
                   truth: Mapping[str, float] | None = None) -> tuple[list[Any], dict[str, float]]:
    """Distances from ``stations`` stations to the tool marker at every pose.

    ``rho = |p - s_k| (- L0_k)`` + N(0, noise^2) [m]; incremental stations were zeroed at
    a random home configuration (``L0_k`` its distance).
    """
    if int(stations) < 1:
        raise MeasurementFileError("option stations must be >= 1")
    incremental = as_flag(incremental, "incremental")
    labels = labels_for(stations, "s")
    K = len(labels)
    q = random_configurations(true_robot, n_poses, rng, margin)
    mode = "incremental" if incremental else "absolute"
    st = np.repeat(np.array(labels)[None], len(q), 0).reshape(-1).tolist()
    qq = np.repeat(q, K, axis=0)
    sigma = stated_sigma(noise, "m")
    probe = RangeMeasurement(name, qq, st, np.zeros(len(qq)), sigma, [mode] * len(qq),
                             marker=marker)
    names = probe.parameters().names
    if truth is not None:
        values = truth_values(truth, names)
    else:
        centre, radius = workspace(true_robot, rng, margin)
        S = _stations_around(rng, centre, K, (1.5, 2.5), (-0.4, 0.8))
        L0 = np.zeros(0)
        if incremental:
            home = random_configurations(true_robot, 1, rng, margin)
            L0 = np.linalg.norm(tool_points(true_robot, home, None)[0] - S, axis=1)
        values = np.concatenate([S.reshape(-1), L0] + ([marker_truth(rng)]
                                                      if marker == "own" else []))
    probe_e = probe.evaluate(true_robot, values, jacobian=False)[0] * sigma   # pred - 0
    rho = probe_e + (rng.normal(0.0, noise, len(qq)) if noise > 0 else 0.0)
    block = RangeMeasurement(name, qq, st, rho, sigma, [mode] * len(qq), marker=marker)
    return [block], dict(zip(names, values.tolist(), strict=True))


# ---------------------------------------------------------------------------- bearing
def simulate_bearing(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                     stations: int = 2, marker: str = "own", name: str = "theodolite",
                     margin: float = 0.05, truth: Mapping[str, float] | None = None
                     ) -> tuple[list[Any], dict[str, float]]:
    """Horizontal and vertical angles from ``stations`` levelled theodolites [rad]."""
    if int(stations) < 1:
        raise MeasurementFileError("option stations must be >= 1")
    labels = labels_for(stations, "t")
    K = len(labels)
    q = random_configurations(true_robot, n_poses, rng, margin)
    st = np.repeat(np.array(labels)[None], len(q), 0).reshape(-1).tolist()
    qq = np.repeat(q, K, axis=0)
    sigma = stated_sigma(noise, "rad")
    probe = BearingMeasurement(name, qq, st, np.zeros((len(qq), 2)), sigma, marker=marker)
    names = probe.parameters().names
    if truth is not None:
        values = truth_values(truth, names)
    else:
        centre, _ = workspace(true_robot, rng, margin)
        S = _stations_around(rng, centre, K, (2.0, 3.0), (-0.3, 0.3))
        frames = np.column_stack([S, rng.uniform(-np.pi, np.pi, K),
                                  rng.normal(0, 2e-3, (K, 2))])       # levelled to ~0.1 deg
        values = np.concatenate([frames.reshape(-1)] + ([marker_truth(rng)]
                                                        if marker == "own" else []))
    m = values[-3:] if marker == "own" else None
    p = tool_points(true_robot, qq, m)
    x = to_local(values[: 6 * K].reshape(K, 6), probe.station_index, p, False)[0]
    ang = bearing_angles(x, False)[0]
    if noise > 0:
        ang = ang + rng.normal(0.0, noise, ang.shape)
    block = BearingMeasurement(name, qq, st, ang, sigma, marker=marker)
    return [block], dict(zip(names, values.tolist(), strict=True))


# ---------------------------------------------------------------------------- cameras
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
        eyes = _stations_around(rng, centre, C, (2.0, 3.0), (0.3, 1.0))
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
        where = _stations_around(rng, centre, 1, (0.9, 1.1), (-0.2, 0.2))[0]
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
