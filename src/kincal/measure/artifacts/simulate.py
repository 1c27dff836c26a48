"""Simulated artifact experiments: place the artifact, seat the probe by IK, read the encoders.

One placement:

1. a configuration ``q_c`` is drawn inside the joint limits (shrunk by ``margin``) such
   that the probe points downwards (within 60 deg of -z, when such draws exist); the
   artifact's centre is put at the probe tip ``P(q_c)`` with its socket axes ``n``
   along the probe (tilted by up to ``tilt_deg``, turned at random about ``n``);
2. every socket ``s = c + R_art l_s`` (``l_s`` the layout) is visited ``visits`` times:
   the seated tip is ``s + e_seat`` (``e_seat ~ N(0, point_std^2)`` per coordinate: the
   seating repeatability), the probe axis is ``-n`` tilted by up to ``cone_deg`` about
   a random axis and turned at random about itself, and the flange pose
   ``T_e = (R, s - R t)`` is solved by :func:`kincal.motion.ik.solve_ik` on the *true* robot
   (starting from ``q_c``);
3. the recorded joint readings are ``q + e_q``, ``e_q ~ N(0, joint_std^2)`` per joint.

Placements with a socket the IK cannot reach (limits, workspace) are discarded and
drawn again.  All randomness comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.measure.artifacts.geometry import ArtifactGeometry
from kincal.measure.artifacts.model import ArtifactMeasurement
from kincal.measure.artifacts.probe import Probe
from kincal.motion.ik import solve_ik
from kincal.robots.chain import Robot
from kincal.spatial import exp_so3

Array = NDArray[np.float64]

#: Draws of candidate placements per missing placement and round.
_OVERDRAW = 2
_ROUNDS = 12


@dataclass(frozen=True)
class ArtifactSimulation:
    """The truth behind a simulated artifact block.

    Attributes:
        frames: (Np, 4, 4) artifact frames in the robot's world frame [m].
        sockets: (N, 3) true socket point of every row (before seating noise) [m].
        q_true: (N, n) the configurations that seat the tip exactly (noise-free readings).
        tip: (3,) the true probe tip in the end frame [m].
    """

    frames: Array
    sockets: Array
    q_true: Array
    tip: Array


def _unit_perpendicular(n: Array, rng: np.random.Generator) -> Array:
    """Random unit vectors perpendicular to the unit vectors ``n`` (K, 3)."""
    a = rng.standard_normal(n.shape)
    a -= np.sum(a * n, axis=1, keepdims=True) * n
    value: Array = a / np.linalg.norm(a, axis=1, keepdims=True)
    return value


def _tilted(n: Array, max_deg: float, rng: np.random.Generator) -> Array:
    """``n`` tilted by an angle uniform in solid angle within ``max_deg`` (K, 3)."""
    c = rng.uniform(np.cos(np.radians(max_deg)), 1.0, len(n))
    ang = np.arccos(c)
    return exp_so3(_unit_perpendicular(n, rng) * ang[:, None]) @ n[:, :, None]


def _frames_about(z: Array, rng: np.random.Generator) -> Array:
    """Rotations (K, 3, 3) with third column ``z`` and a random spin about it."""
    x = _unit_perpendicular(z, rng)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def _centres(robot: Robot, probe_tip: Array, count: int, rng: np.random.Generator,
             margin: float) -> tuple[Array, Array, Array]:
    """Candidate centres: tips (K, 3), downward probe axes (K, 3), configurations (K, n)."""
    from kincal.measure.simulate import random_configurations

    q = random_configurations(robot, 8 * count, rng, margin)
    T = robot.fk(q)
    tips = T[:, :3, 3] + T[:, :3, :3] @ probe_tip
    axis = T[:, :3, 2]
    down = axis[:, 2] < -0.5
    order = np.r_[np.flatnonzero(down), np.flatnonzero(~down)][:count]
    return tips[order], axis[order], q[order]


def seat(true_robot: Robot, sockets: Array, normals: Array, tip: Array, q0: Array,
         rng: np.random.Generator, cone_deg: float) -> tuple[Array, NDArray[np.bool_]]:
    """Configurations seating ``tip`` in ``sockets`` (K, 3) approached along ``-normals``.

    Returns ``(q (K, n), success (K,))``.
    """
    z = -_tilted(normals, cone_deg, rng)[..., 0]
    R = _frames_about(z, rng)
    T = np.zeros((len(sockets), 4, 4))
    T[:, :3, :3] = R
    T[:, :3, 3] = sockets - R @ tip
    T[:, 3, 3] = 1.0
    sol = solve_ik(true_robot, T, q0=q0, mask="pose", tol_position=1e-10,
                   tol_orientation=1e-9, restarts=3, rng=rng)
    return sol.q, sol.success


def simulate_artifact(true_robot: Robot, geometry: ArtifactGeometry, placements: int,
                      rng: np.random.Generator, probe: Probe | None = None,
                      true_tip: Array | None = None, joint_std: float = 0.0,
                      point_std: float = 0.0, visits: int = 1, sockets: str = "eliminate",
                      name: str = "artifact", tilt_deg: float = 20.0, cone_deg: float = 30.0,
                      margin: float = 0.05, model_robot: Robot | None = None,
                      label_prefix: str = "") -> tuple[ArtifactMeasurement,
                                                       ArtifactSimulation]:
    """Simulate ``placements`` placements of an artifact measured with the true robot.

    Args:
        true_robot: the robot that really moves.
        geometry: the artifact (its ``layout`` places the sockets).
        placements: number of placements.
        probe: the probe as the block will describe it (default: the robot's tool origin).
        true_tip: the real tip in the end frame [m] (default ``probe.tip()``).
        joint_std: encoder noise [rad / m] added to the recorded readings.
        point_std: seating repeatability [m] (per coordinate).
        visits: seatings per socket and placement (several: coincidence data).
        sockets: the block's socket mode.
        name: block name.
        tilt_deg: tilt of the artifact's socket axes from the probe at its centre.
        cone_deg: largest tilt of the probe from the socket axis when seated.
        margin: fraction of each joint range kept away from the limits when drawing.
        model_robot: the model the block's noise is propagated with (default the true
            robot; the weights hardly depend on it).
        label_prefix: prefix of the placement labels (``"v"`` for held-out data).

    Returns:
        ``(block, truth)``; rows are ordered placement by placement, socket by socket
        (geometry order), visit by visit.
    """
    if placements < 1 or visits < 1:
        raise KincalError("an artifact simulation needs placements >= 1 and visits >= 1")
    probe = probe if probe is not None else Probe.tool()
    tip = probe.tip() if true_tip is None else np.asarray(true_tip, dtype=float).reshape(3)
    layout = geometry.layout_array()
    K = len(geometry.sockets)
    got_q: list[Array] = []
    got_s: list[Array] = []
    got_f: list[Array] = []
    for _ in range(_ROUNDS):
        need = placements - len(got_f)
        if need <= 0:
            break
        m = _OVERDRAW * need + 2
        c, axis, qc = _centres(true_robot, tip, m, rng, margin)
        n_art = -_tilted(axis, tilt_deg, rng)[..., 0]             # socket axes (out of cups)
        R_art = _frames_about(n_art, rng)
        S = c[:, None, :] + np.einsum("mij,kj->mki", R_art, layout)  # (m, K, 3)
        S = np.repeat(S, visits, axis=1)                          # (m, K * v, 3)
        targets = S + point_std * rng.standard_normal(S.shape)
        normals = np.repeat(n_art[:, None, :], K * visits, axis=1)
        q0 = np.repeat(qc, K * visits, axis=0)
        q, ok = seat(true_robot, targets.reshape(-1, 3), normals.reshape(-1, 3), tip, q0, rng,
                     cone_deg)
        ok = np.asarray(ok.reshape(m, K * visits).all(axis=1))
        for i in np.flatnonzero(ok)[:need]:
            got_q.append(q.reshape(m, K * visits, -1)[i])
            got_s.append(S[i])
            F = np.eye(4)
            F[:3, :3], F[:3, 3] = R_art[i], c[i]
            got_f.append(F)
    if len(got_f) < placements:
        raise KincalError(f"could seat the probe in every socket of only {len(got_f)} of "
                          f"{placements} placements of the {geometry.kind} (the artifact "
                          "may be too large for the workspace, or the probe too long)")
    q_true = np.concatenate(got_q)
    q_rec = q_true + joint_std * rng.standard_normal(q_true.shape) if joint_std > 0 \
        else q_true.copy()
    labels = [f"{label_prefix}{i + 1}" for i in range(placements)]
    placement = np.repeat(labels, K * visits).tolist()
    socket = np.tile(np.repeat(geometry.sockets, visits), placements).tolist()
    block = ArtifactMeasurement(q_rec, placement, socket, geometry, probe, sockets, name,
                                joint_std=joint_std,
                                point_std=point_std if point_std > 0 else
                                (0.0 if joint_std > 0 else 1e-5),
                                robot=model_robot or true_robot)
    return block, ArtifactSimulation(np.stack(got_f), np.concatenate(got_s), q_true, tip)


def truth_of(block: ArtifactMeasurement, sim: ArtifactSimulation) -> dict[str, float]:
    """``{parameter name: true value}`` of a simulated block's own parameters."""
    spec = block.parameters()
    values: list[float] = []
    if block.probe.estimate:
        values += [float(sim.tip[2])] if block.probe.mode == "length" else sim.tip.tolist()
    if block.sockets == "parameters":
        first = np.zeros(block.sites.S, dtype=np.intp)
        first[block.sites.index[::-1]] = np.arange(block.N)[::-1]
        values += sim.sockets.reshape(-1, 3)[first].reshape(-1).tolist()
    values += [0.0] * (3 * len(block.framed_sites))      # socket frames: a gauge, 0
    return dict(zip(spec.names, values, strict=True))


def probe_from_truth(probe: Probe, name: str, truth: Mapping[str, float] | None
                     ) -> Array | None:
    """The true tip stored in a previous ``truth`` dict, if any."""
    if not truth or not probe.estimate:
        return None
    keys = [f"{name}.probe.l"] if probe.mode == "length" else \
        [f"{name}.probe.{c}" for c in "xyz"]
    if not all(k in truth for k in keys):
        return None
    v = np.array([float(truth[k]) for k in keys])
    return np.array([0.0, 0.0, v[0]]) if probe.mode == "length" else v


# --------------------------------------------------------------------------- registry
def _probe_option(kind: str, length: float, error: float, rng: np.random.Generator
                  ) -> tuple[Probe, Array]:
    """The block's probe and the true tip for the ``probe`` option."""
    nominal = np.array([0.0, 0.0, length])
    if kind == "known":
        return Probe.length(length), nominal
    if kind == "length":
        return Probe.length(length, True), nominal + [0.0, 0.0, error * rng.standard_normal()]
    if kind == "vector":
        return Probe.vector(nominal, True), nominal + error * rng.standard_normal(3)
    if kind == "tool":
        return Probe.tool(), np.zeros(3)
    raise KincalError(f"option probe: {kind!r} is not known, length, vector or tool")


def simulate_instrument(kind: str, true_robot: Robot, rng: np.random.Generator, n_poses: int,
                        noise: float, *, placements: int = 0, length_mm: float = 300.0,
                        probe: str = "known", probe_length_mm: float = 100.0,
                        probe_error_mm: float = 0.5, encoder_noise_deg: float = -1.0,
                        seat_noise_mm: float = 0.0, length_std_mm: float = 0.0,
                        angle_std_deg: float = 0.0, visits: int = 1,
                        sockets: str = "eliminate", cone_deg: float = 30.0,
                        tilt_deg: float = 20.0, margin: float = 0.05, name: str = "",
                        truth: Mapping[str, float] | None = None
                        ) -> tuple[list[ArtifactMeasurement], dict[str, float]]:
    """Registry entry: simulate a built-in artifact ``kind`` (see :func:`simulate_artifact`).

    ``noise`` is the encoder noise [rad] unless ``encoder_noise_deg >= 0``;
    ``placements = 0`` takes ``n_poses / (sockets x visits)`` placements.  With
    ``truth`` (held-out data) the probe keeps its true tip and the placements are new
    (labelled ``v1, v2 ...``).
    """
    geometry = ArtifactGeometry.builtin(kind, length_mm * 1e-3, length_std_mm * 1e-3,
                                        np.radians(angle_std_deg))
    K = len(geometry.sockets)
    n_pl = placements if placements > 0 else max(1, int(n_poses) // (K * max(visits, 1)))
    joint_std = np.radians(encoder_noise_deg) if encoder_noise_deg >= 0 else float(noise)
    name = name or {"cross-bar": "cross", "ball-bar": "ballbar", "two-socket": "sockets"}[kind]
    prb, tip = _probe_option(probe, probe_length_mm * 1e-3, probe_error_mm * 1e-3, rng)
    old = probe_from_truth(prb, name, truth)
    if old is not None:
        tip = old
    block, sim = simulate_artifact(true_robot, geometry, n_pl, rng, prb, tip, joint_std,
                                   seat_noise_mm * 1e-3, visits, sockets, name, tilt_deg,
                                   cone_deg, margin, label_prefix="v" if truth else "")
    return [block], truth_of(block, sim)


def simulate_cross_bar(true_robot: Robot, rng: np.random.Generator, n_poses: int,
                       noise: float, bar_length_mm: float = 300.0, **options: object
                       ) -> tuple[list[ArtifactMeasurement], dict[str, float]]:
    """``cross-bar``: sockets A, B, C, D, ``|AC| = |BD| = bar_length_mm``, AC perpendicular
    to BD; one seating per socket and placement by default."""
    return simulate_instrument("cross-bar", true_robot, rng, n_poses, noise,
                               length_mm=bar_length_mm, **options)  # type: ignore[arg-type]


def simulate_ball_bar(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                      bar_length_mm: float = 200.0, **options: object
                      ) -> tuple[list[ArtifactMeasurement], dict[str, float]]:
    """``ball-bar``: two sockets A, B at ``bar_length_mm``; one seating each per placement."""
    return simulate_instrument("ball-bar", true_robot, rng, n_poses, noise,
                               length_mm=bar_length_mm, **options)  # type: ignore[arg-type]


def simulate_two_socket(true_robot: Robot, rng: np.random.Generator, n_poses: int,
                        noise: float, socket_distance_mm: float = 50.0, visits: int = 15,
                        **options: object
                        ) -> tuple[list[ArtifactMeasurement], dict[str, float]]:
    """``two-socket``: sockets hole_0, hole_1 at ``socket_distance_mm``, each seated
    ``visits`` times per placement in different orientations."""
    return simulate_instrument("two-socket", true_robot, rng, n_poses, noise,
                               length_mm=socket_distance_mm, visits=visits,
                               **options)  # type: ignore[arg-type]
