"""Virtual contacts: the tool point placed on planes and on fixture points.

The contact configurations are solved on the true robot by minimum-norm Newton steps in
joint space (:func:`solve_contacts`), so the joint readings are exact and the noise sits in
the contact itself (the point is off the plane / fixture point by N(0, noise^2) [m]).
Signatures as in :mod:`.simulate`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.instruments.fixture import FixtureMeasurement
from kincal.measure.instruments.plane import PlaneMeasurement
from kincal.measure.instruments.simulate import (
    as_flag,
    labels_for,
    marker_truth,
    stated_sigma,
    tool_points,
    truth_values,
    workspace,
)
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot
from kincal.spatial import exp_so3

Array = NDArray[np.float64]


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


# ---------------------------------------------------------------------------- plane
def simulate_plane(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                   planes: int = 4, known: bool = False, marker: str = "own",
                   name: str = "plane", margin: float = 0.05) -> tuple[list[Any], dict[str, float]]:
    """Contacts of the tool marker with ``planes`` planes, ``n_poses`` in all.

    The planes cut the workspace with normals spread over directions; the contact
    distance has noise N(0, noise^2) [m].  Unknown planes are written with a nominal
    normal ~1 deg off the true one (the reference of their tilt parameters), so every
    simulation has its own planes (no ``truth=`` re-measurement).
    """
    G = int(planes)
    if G < 1:
        raise MeasurementFileError("option planes must be >= 1")
    known = as_flag(known, "known")
    labels = labels_for(G, "p")
    centre, radius = workspace(true_robot, rng, margin)
    axes = exp_so3(rng.normal(0, 0.5, 3))
    normals = np.vstack([axes.T, rng.normal(size=(max(G - 3, 0), 3))])[:G]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    d = normals @ centre + rng.uniform(-0.3, 0.3, G) * radius
    nominal = normals + rng.normal(0, 0.015, normals.shape)
    nominal /= np.linalg.norm(nominal, axis=1, keepdims=True)
    m = marker_truth(rng) if marker == "own" else None
    defs = {s: (normals[g] if known else nominal[g], d[g], bool(known))
            for g, s in enumerate(labels)}
    probe = PlaneMeasurement(name, np.zeros((G, true_robot.n)), labels, 1.0, defs, marker)
    own: list[float] = []
    if not known:
        for g in range(G):
            nl = probe.bases[g].T @ normals[g]
            own += [-np.arcsin(nl[1]), np.arctan2(nl[0], nl[2]), d[g]]
    values = np.array(own + ([] if m is None else list(m)))
    which = np.arange(4 * n_poses) % G
    q0 = random_configurations(true_robot, len(which), rng, margin)
    eps = rng.normal(0.0, noise, len(which)) if noise > 0 else np.zeros(len(which))
    q, ok = solve_contacts(true_robot, q0, m, normals[which][:, None, :],
                           (d[which] + eps)[:, None])
    keep = np.concatenate([np.flatnonzero(ok & (which == g))[: (n_poses + g) // G]
                           for g in range(G)])
    keep.sort()
    if len(keep) < n_poses:
        raise KincalError(f"only {len(keep)} of {n_poses} plane contacts are reachable")
    block = PlaneMeasurement(name, q[keep], [labels[g] for g in which[keep]],
                             stated_sigma(noise, "m"), defs, marker)
    return [block], dict(zip(probe.parameters().names, values.tolist(), strict=True))


# ---------------------------------------------------------------------------- fixture
def simulate_fixture(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                     points: int = 8, marker: str = "own", name: str = "fixture",
                     margin: float = 0.05, truth: Mapping[str, float] | None = None
                     ) -> tuple[list[Any], dict[str, float]]:
    """The tool marker placed on ``points`` known fixture points, ``n_poses`` contacts.

    Each point is approached in several orientations; the placement error is
    N(0, noise^2) per coordinate [m].  Fixture points are drawn inside the reachable
    workspace; their world coordinates are exact (pre-calibrated).
    """
    F = int(points)
    if F < 1:
        raise MeasurementFileError("option points must be >= 1")
    probe = FixtureMeasurement(name, np.zeros((1, true_robot.n)), np.zeros((1, 3)), 1.0,
                               marker)
    names = probe.parameters().names
    mt = marker_truth(rng)
    if truth is not None:
        values = truth_values(truth, names)
    else:
        values = mt if marker == "own" else np.zeros(0)
    m = values if marker == "own" else None
    anchors = random_configurations(true_robot, F, rng, 0.2)
    fix = tool_points(true_robot, anchors, m)
    which = np.arange(4 * n_poses) % F
    q0 = anchors[which] + rng.normal(0.0, 0.6, (len(which), true_robot.n))
    eps = rng.normal(0.0, noise, (len(which), 3)) if noise > 0 else np.zeros((len(which), 3))
    A = np.broadcast_to(np.eye(3), (len(which), 3, 3))
    q, ok = solve_contacts(true_robot, q0, m, A, fix[which] + eps)
    keep = np.flatnonzero(ok)[:n_poses]
    if len(keep) < n_poses:
        raise KincalError(f"only {len(keep)} of {n_poses} fixture contacts are reachable")
    block = FixtureMeasurement(name, q[keep], fix[which[keep]], stated_sigma(noise, "m"),
                               marker)
    return [block], dict(zip(names, values.tolist(), strict=True))
