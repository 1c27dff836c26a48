"""What the virtual instruments share (each measures a "true" robot like its instrument).

Every simulator has the registry signature
``simulate(true_robot, rng, n_poses, noise, **options) -> ([block], truth)``: joint
configurations drawn uniformly inside the limits (:func:`random_configurations`), the
instrument placed plausibly around the robot's workspace, independent Gaussian noise of
standard deviation ``noise`` (m for range/plane/fixture, rad for bearing, px for
camera) on every observation, and ``truth`` = ``{parameter name: true value}`` of the
block's own parameters.  Passing ``truth=`` back re-measures with the same placement
(held-out data).  Each simulator lives in its instrument's module
(:mod:`.range`, :mod:`.bearing`, :mod:`.camera`, :mod:`.plane`, :mod:`.fixture`, and
the trackers :mod:`.position`, :mod:`.pose`); this module holds what they share: the
workspace and station placement, stated sigmas and truth look-up, the simulation options
every point instrument takes, and the contact solver of the contact instruments (the
contact configurations are solved on the true robot by minimum-norm Newton steps in joint
space, so the joint readings are exact and the noise sits in the contact itself).  Not
modelled: occlusion by the robot, refraction, lens distortion.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import MeasurementFileError
from kincal.measure.instruments.common import rotation_to_rpy_frame
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot

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
    """The sigma a simulated block states: ``noise``, or :data:`EXACT_SIGMA` when 0."""
    return float(noise) if noise > 0 else EXACT_SIGMA[unit]


def truth_values(truth: Mapping[str, float], names: Sequence[str]) -> Array:
    """The values of ``names`` in a previous simulation's ``truth`` (same placement)."""
    missing = [n for n in names if n not in truth]
    if missing:
        raise MeasurementFileError(f"instrument truth lacks {missing[0]!r}")
    return np.array([float(truth[n]) for n in names])


def stations_around(rng: np.random.Generator, centre: Array, k: int, dist: tuple[float, float],
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
    """``k`` station labels ``prefix1 ... prefixk``."""
    return [f"{prefix}{i + 1}" for i in range(int(k))]


# ---------------------------------------------------------------------------- range


# ---------------------------------------------------------------------------- bearing


# ---------------------------------------------------------------------------- cameras


#: Simulation options every point instrument (range, bearing, camera, plane, fixture) takes.
POINT_OPTIONS: dict[str, tuple[object, str]] = {
    "marker": ("own", "'own': the block's marker parameters; 'tool': the robot's tool "
                      "origin (share one marker between instruments)"),
    "margin": (0.05, "fraction of each joint range kept away from the limits"),
}


# ---------------------------------------------------------------------------- contacts
def point_jacobian(robot: Robot, q: Array, m: Array | None) -> tuple[Array, Array]:
    """Marker positions (N, 3) and their joint Jacobians (N, 3, n)."""
    T, J, _ = robot.fk_with_jacobians(q, joints=True, params=False)
    assert J is not None                               # joints=True
    if m is None:
        return T[:, :3, 3], J[:, :3]
    Rm = T[:, :3, :3] @ m
    return T[:, :3, 3] + Rm, J[:, :3] + np.cross(J[:, 3:], Rm[:, :, None], axis=1)


def solve_contacts(robot: Robot, q0: Array, m: Array | None, A: Array, b: Array,
                   iterations: int = 40) -> tuple[Array, NDArray[np.bool_]]:
    """Joint values with ``A_i p(q_i) = b_i`` by minimum-norm Newton steps from ``q0``.

    ``A`` (N, k, 3), ``b`` (N, k).  Returns ``q`` and a mask of rows that converged
    (constraint below 1e-13 m) inside the joint limits.
    """
    q = q0.copy()
    for _ in range(iterations):
        p, Jp = point_jacobian(robot, q, m)
        g = np.einsum("nkj,nj->nk", A, p) - b
        Jg = A @ Jp
        JJ = Jg @ np.swapaxes(Jg, 1, 2)
        step = np.linalg.solve(JJ + 1e-12 * np.eye(A.shape[1]), g[:, :, None])
        q = q - (np.swapaxes(Jg, 1, 2) @ step)[:, :, 0]
    p = point_jacobian(robot, q, m)[0]
    g = np.einsum("nkj,nj->nk", A, p) - b
    lim = robot.joint_limits
    ok = (np.max(np.abs(g), axis=1) < 1e-13) & np.all((q >= lim[:, 0]) & (q <= lim[:, 1]), 1)
    return q, ok

