"""Plan a camera calibration: robot poses that see the whole board and excite what the
hand-eye fit has not yet identified.

Geometry (lengths in m, angles in rad).  Eye-in-hand (``mount="hand"``): the camera sits
at ``X`` in the robot's tool frame, the board lies at ``Z`` in the base frame, and the
board's pose in the camera at joints ``q`` is ``B(q) = (T(q) X)^-1 Z``.  Eye-to-hand
(``"fixed"``): the camera is at ``X`` in the base frame, the board at ``Z`` in the tool
frame, ``B(q) = X^-1 T(q) Z``.  A board corner ``P`` projects with the pinhole
``u = fx x1/x3 + cx, v = fy x2/x3 + cy`` of ``x = B P``.

Default placements (:func:`default_placement`, at the ``center`` configuration): the
board's centre on the optical axis at ``distance`` (default: the board fills half the
image, ``d = max(fx w_board / (0.5 W), fy h_board / (0.5 H))``), its printed face towards
the camera (OpenCV's board frame: x along the first row of corners, z into the board, away
from the viewer: the board's axes are the camera's); eye-in-hand ``X = I`` (the camera
looks along the tool's z), eye-to-hand the board centred on the flange, its printed face
along the tool's z (``Z = Rx(pi)`` about its centre).

A candidate pose **sees the board** (:func:`board_view`) when

1. every corner is at least 5 cm in front of the camera and projects inside the image
   shrunk by ``margin`` (a fraction of its width and height, default 5 %);
2. the board is not too oblique, and its printed face is seen: the angle between its z
   axis and the ray from the camera to its centre is at most ``max_tilt`` (default
   45 deg; ``kincal import images`` drops images beyond 60 deg);
3. the board is not too far: the diagonal of its corners' bounding box in the image is
   at least ``min_size`` (default 0.2) of the image diagonal.

Candidates are random configurations ``center + U(-spread, spread)`` per joint (default
30 deg), clipped to the joint limits, and only those that see the board are kept.

Design.  The measurement model is the one the fit uses: eye-in-hand
:class:`~kincal.measure.instruments.camera.HandCameraMeasurement` (the robot's tool frame
is the camera, ``tool <- tool X``; the block's ``camera.target.*`` the board), eye-to-hand
:class:`~kincal.identify.hand_eye_fixed.BoardOnFlangeMeasurement` (``tool <- tool Z``;
``camera.camera.*`` the camera), built with the nominal pixels of every candidate corner.
The parameters designed for are the hand-eye and the board (six each) and the robot
parameters ``free``, reduced to the base set the candidates identify with the hand-eye and
the board kept first (as the fit's ``prefer``); the rest are named as not identifiable.
Every candidate contributes its corners' whitened rows (``sigma`` px per coordinate);
``poses`` of them are chosen by :func:`~kincal.identify.design.select_poses` (O1: greedy
D-optimal + DETMAX), so rotations about all axes (what the hand-eye needs) and the robot
parameters are excited together.  The intrinsics are taken as known (a design for
``--lens all`` would need them in the model).

Prediction: ``Cov = (sum_{i in S} J_i^T J_i)^-1`` over the base set (whitened rows: in the
parameters' units, the corner noise ``sigma`` included), the hand-eye's position error
``sqrt(trace Cov_xyz)`` [m] and rotation error ``sqrt(trace(A Cov_rot A^T))`` [rad] with
``A`` the world axes of the ``rz, ry, rx`` angles (a small rotation vector is ``A d``).
The same for :data:`RANDOM_DESIGNS` random designs of the same size from the same visible
candidates, the median quoted as the baseline.  Measured (``python
benchmarks/camera_plan.py --trials 40``: Panda, hand camera, 5x7 board, 12 poses, joint
offsets free, 0.5 px): predicted 0.130 mm / 0.0202 deg, Monte Carlo of fits at the
planned poses 0.117 mm / 0.0202 deg (ratio 0.90 / 1.00); 12 random visible poses
0.267 mm / 0.0326 deg.  Eye-to-hand (``--mount fixed``, 30 sets): predicted 0.246 mm /
0.0246 deg, Monte Carlo 0.227 mm / 0.0249 deg (0.92 / 1.01); random 0.522 mm / 0.0643 deg.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.identify.design import PoseDesign, random_design, select_poses, within_limits
from kincal.identify.hand_eye_fixed import BoardOnFlangeMeasurement
from kincal.identify.identifiability import analyze, default_priority
from kincal.identify.names import match_names
from kincal.identify.observability import DesignProblem, design_problem_from_blocks
from kincal.measure.base import MeasurementModel, stack
from kincal.measure.instruments.camera import HandCameraMeasurement
from kincal.measure.instruments.common import frame_axes
from kincal.robots.chain import Robot
from kincal.spatial import frame_from_matrix, inverse, matrix_from_frame

Array = NDArray[np.float64]

__all__ = ["CameraPlan", "BoardView", "board_view", "default_placement", "plan_camera_poses",
           "predicted_hand_eye_std", "write_camera_poses", "RANDOM_DESIGNS"]

TOOL = tuple(f"tool.{f}" for f in ("x", "y", "z", "rz", "ry", "rx"))
#: Random designs of the baseline.
RANDOM_DESIGNS = 20


def _rx_pi() -> Array:
    return np.diag([1.0, -1.0, -1.0, 1.0])


def _shift(p: ArrayLike) -> Array:
    T = np.eye(4)
    T[:3, 3] = np.asarray(p, dtype=float)
    return T


def default_placement(robot: Robot, center: ArrayLike, corners: Array, mount: str,
                      distance: float, X: Array | None = None, Z: Array | None = None
                      ) -> tuple[Array, Array]:
    """``(X, Z)`` (module docstring): the board's centre on the optical axis at
    ``distance`` [m] at the ``center`` joints, facing the camera; a given ``X`` or ``Z``
    is kept."""
    Tc = robot.fk(np.asarray(center, dtype=float))
    c = corners.mean(axis=0)
    face = _shift([0.0, 0.0, distance])     # the board centre's frame in the camera
    if mount == "hand":
        Xh = np.eye(4) if X is None else X
        return Xh, (Tc @ Xh @ face @ _shift(-c) if Z is None else Z)
    if mount != "fixed":
        raise KincalError(f"mount={mount!r}: use 'hand' or 'fixed'")
    Zf = _rx_pi() @ _shift(-c) if Z is None else Z
    return (Tc @ Zf @ _shift(c) @ inverse(face) if X is None else X), Zf


def _board_in_camera(T: Array, X: Array, Z: Array, mount: str) -> Array:
    if mount == "hand":
        return np.asarray(inverse(T @ X) @ Z, dtype=float)
    return np.asarray(inverse(X) @ T @ Z, dtype=float)


@dataclass
class BoardView:
    """The board as each configuration's camera sees it: ``uv`` (N, M, 2) [px], the
    tilt [deg] and depth of its centre [m], its image size (bounding-box diagonal over
    the image diagonal) and ``ok`` (N,) for the three conditions of the module
    docstring."""

    uv: Array
    tilt_deg: Array
    depth: Array
    size: Array
    ok: NDArray[np.bool_]


def board_view(robot: Robot, q: ArrayLike, corners: Array, X: Array, Z: Array, mount: str,
               intrinsics: Sequence[float], image_size: Sequence[float], margin: float = 0.05,
               max_tilt_deg: float = 45.0, min_size: float = 0.2) -> BoardView:
    """Project ``corners`` (M, 3) [m] at every configuration ``q`` (N, n) and check the
    conditions of the module docstring (``image_size`` = width, height [px])."""
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    W, H = (float(v) for v in image_size)
    B = _board_in_camera(robot.fk(np.atleast_2d(np.asarray(q, dtype=float))), X, Z, mount)
    x = np.einsum("nij,mj->nmi", B[:, :3, :3], corners) + B[:, None, :3, 3]
    z = np.where(np.abs(x[..., 2]) > 1e-9, x[..., 2], 1e-9)
    uv = np.stack([fx * x[..., 0] / z + cx, fy * x[..., 1] / z + cy], axis=-1)
    inside = ((uv[..., 0] >= margin * W) & (uv[..., 0] <= (1 - margin) * W)
              & (uv[..., 1] >= margin * H) & (uv[..., 1] <= (1 - margin) * H)
              & (x[..., 2] > 0.05)).all(axis=1)
    centre = np.einsum("nij,j->ni", B[:, :3, :3], corners.mean(axis=0)) + B[:, :3, 3]
    ray = centre / np.linalg.norm(centre, axis=1, keepdims=True)
    tilt = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", B[:, :3, 2], ray), -1, 1)))
    size = np.hypot(*(uv.max(axis=1) - uv.min(axis=1)).T) / np.hypot(W, H)
    ok = inside & (tilt <= max_tilt_deg) & (size >= min_size)
    return BoardView(uv, tilt, centre[:, 2], size, ok)


def _block(robot: Robot, q: Array, corners: Array, uv: Array, mount: str,
           intrinsics: Sequence[float], sigma: float) -> MeasurementModel:
    Q = np.repeat(q, len(corners), axis=0)
    S = np.tile(corners, (len(q), 1))
    if mount == "hand":
        return HandCameraMeasurement("camera", Q, S, uv.reshape(-1, 2), sigma, intrinsics)
    return BoardOnFlangeMeasurement("camera", Q, S, uv.reshape(-1, 2), sigma, intrinsics)


def _design_robot(robot: Robot, X: Array, Z: Array, mount: str) -> tuple[Robot, Array]:
    """The robot whose tool frame is the camera (hand) or the board (fixed), and the
    block's own parameters (the board in the base, or the camera in the base)."""
    tool0 = matrix_from_frame(robot.frame_parameters("tool"))
    inner, extra = (X, Z) if mount == "hand" else (Z, X)
    r = robot.with_params(dict(zip(TOOL, frame_from_matrix(tool0 @ inner).tolist(),
                                   strict=True)))
    return r, frame_from_matrix(extra)


def _base_names(robot: Robot, block: MeasurementModel, extra: Array, free: Sequence[str]
                ) -> tuple[list[str], dict[str, str]]:
    """The base set of hand-eye, board and ``free`` (the first two kept first, as the
    fit's ``prefer``) and ``{name: why not}`` for the robot parameters left out."""
    prob, theta = stack(robot, [block])
    theta[prob.num_robot:] = extra
    _, J = prob.residuals_and_jacobian(theta)
    own = list(block.parameters().names)
    wanted = ([robot.param_names[i] for i in match_names(robot.param_names, list(free))]
              if free else [])
    cand = [*TOOL, *own, *(n for n in wanted if n not in TOOL)]
    idx = [prob.names.index(n) for n in cand]
    roles = [prob.roles[i] for i in idx]
    pri = default_priority(cand, roles)
    pri[: 6 + len(own)] = -1
    rep = analyze(J[:, idx], cand, roles=roles, priority=pri)
    missing = [n for n in (*TOOL, *own) if n not in rep.identifiable]
    if missing:
        raise KincalError("the candidate poses cannot identify the hand-eye ("
                          + ", ".join(missing) + "): widen --spread or move the board")
    why = {n: ("not seen by the camera" if n in rep.unobservable else "moves the pixels as "
               + ", ".join(rep.dependent.get(n, [])[:3]) + " do")
           for n in wanted if n not in rep.identifiable}
    return list(rep.identifiable), why


def predicted_hand_eye_std(problem: DesignProblem, selected: ArrayLike, he: Sequence[str],
                           angles: Array) -> tuple[float, float, Array]:
    """Position [m] and rotation [rad] standard errors of the hand-eye frame ``he`` (six
    names ``x y z rz ry rx`` of the base set) at the nominal ``angles`` ``(rz, ry)``, and
    the standard error of every base-set parameter (module docstring, "Prediction")."""
    Jsel = problem.J[np.asarray(selected, dtype=np.intp)]
    info = np.einsum("nri,nrj->ij", Jsel, Jsel)
    cov = np.linalg.pinv(info)
    k = [problem.names.index(n) for n in he]
    c = cov[np.ix_(k, k)]
    A = frame_axes(angles[0], angles[1])
    rot = float(np.sqrt(max(np.trace(A @ c[3:, 3:] @ A.T), 0.0)))
    return (float(np.sqrt(max(np.trace(c[:3, :3]), 0.0))), rot,
            np.sqrt(np.clip(np.diag(cov), 0.0, None)))


@dataclass
class CameraPlan:
    """A planned camera calibration (m, rad, px).

    Attributes:
        q: (poses, n) the chosen configurations.
        X, Z: the placements planned with (module docstring).
        view: the chosen poses' :class:`BoardView`.
        design: the :class:`~kincal.identify.design.PoseDesign` over the visible candidates.
        std_position, std_rotation: the hand-eye's predicted standard errors.
        std: ``{base-set name: predicted standard error}``.
        random_position, random_rotation: the same of each random design.
        not_identifiable: ``{robot parameter of free: why}``.
        candidates, visible: candidates drawn and those that see the board.
        inputs: the planning inputs in words.
    """

    q: Array
    X: Array
    Z: Array
    view: BoardView
    design: PoseDesign
    std_position: float
    std_rotation: float
    std: dict[str, float]
    random_position: list[float]
    random_rotation: list[float]
    not_identifiable: dict[str, str] = field(default_factory=dict)
    candidates: int = 0
    visible: int = 0
    inputs: dict[str, str] = field(default_factory=dict)

    @property
    def median_random(self) -> tuple[float, float]:
        """The median random design's ``(position, rotation)`` standard errors."""
        return (float(np.median(self.random_position)),
                float(np.median(self.random_rotation)))


def plan_camera_poses(robot: Robot, corners: Array, intrinsics: Sequence[float],
                      image_size: Sequence[float], mount: str = "hand", poses: int = 15,
                      free: Sequence[str] = (), center: ArrayLike | None = None,
                      spread: float = np.radians(30.0), candidates: int = 2000,
                      X: Array | None = None, Z: Array | None = None,
                      distance: float | None = None, sigma: float = 0.5,
                      margin: float = 0.05, max_tilt_deg: float = 45.0,
                      min_size: float = 0.2, criterion: str = "O1", seed: int = 0
                      ) -> CameraPlan:
    """Choose ``poses`` configurations for a camera calibration (module docstring).

    Args:
        robot: the nominal robot (its tool frame the flange the camera or board is on).
        corners: (M, 3) the board's corners in the board frame [m].
        intrinsics: ``fx, fy, cx, cy`` [px]; image_size: width, height [px].
        mount: ``"hand"`` or ``"fixed"``.
        poses: how many poses to choose.
        free: robot parameters (names or patterns) to design for with the hand-eye.
        center: the configuration the candidates spread around (default mid-range).
        spread: half-width of the uniform spread per joint [rad].
        candidates: random configurations drawn.
        X, Z: the hand-eye and the board placements (default :func:`default_placement`).
        distance: of the board from the camera at ``center`` [m] (default: the board
            fills half the image).
        sigma: corner noise per coordinate [px].
        margin, max_tilt_deg, min_size: the visibility conditions (:func:`board_view`).
        criterion: of :func:`~kincal.identify.design.select_poses`.
        seed: of the candidates and of the random designs.
    """
    rng = np.random.default_rng(seed)
    lim = robot.joint_limits
    qc = lim.mean(axis=1) if center is None else np.asarray(center, dtype=float)
    if not within_limits(robot, qc[None])[0]:
        raise KincalError("the centre configuration is outside the joint limits")
    ext = np.ptp(corners[:, :2], axis=0)
    d = (max(float(intrinsics[k]) * ext[k] / (0.5 * float(image_size[k])) for k in (0, 1))
         if distance is None else float(distance))
    Xp, Zp = default_placement(robot, qc, corners, mount, d, X, Z)
    q = np.clip(qc + rng.uniform(-spread, spread, (candidates, robot.n)), lim[:, 0], lim[:, 1])
    q = np.vstack([qc, q])
    view = board_view(robot, q, corners, Xp, Zp, mount, intrinsics, image_size, margin,
                      max_tilt_deg, min_size)
    qv = q[view.ok]
    if len(qv) < poses:
        raise KincalError(f"only {len(qv)} of {len(q)} candidate poses see the whole board "
                          f"(tilt <= {max_tilt_deg:g} deg, size >= {min_size:g} of the image)"
                          f"; ask for fewer poses, widen --spread or move the board")
    rd, extra = _design_robot(robot, Xp, Zp, mount)
    block = _block(rd, qv, corners, view.uv[view.ok], mount, intrinsics, sigma)
    base, why = _base_names(rd, block, extra, free)
    problem = design_problem_from_blocks(rd, [block], extra, free=base, sigma=sigma)
    design = select_poses(problem, poses, criterion)
    he = list(TOOL) if mount == "hand" else [f"camera.camera.{f}" for f in
                                             ("x", "y", "z", "rz", "ry", "rx")]
    ang = np.array([problem.theta[problem.problem.names.index(he[k])] for k in (3, 4)])
    sp, sr, std = predicted_hand_eye_std(problem, design.selected, he, ang)
    rp, rr = [], []
    for _ in range(RANDOM_DESIGNS):
        r = random_design(problem, poses, rng)
        a, b, _ = predicted_hand_eye_std(problem, r.selected, he, ang)
        rp.append(a)
        rr.append(b)
    sel = np.flatnonzero(view.ok)[design.selected]
    chosen = BoardView(view.uv[sel], view.tilt_deg[sel], view.depth[sel], view.size[sel],
                       view.ok[sel])
    inputs = {"robot": robot.name, "mount": mount, "poses": str(poses),
              "candidates": f"{len(q)} around the centre (+-{np.degrees(spread):.0f} deg per "
                            f"joint), {len(qv)} see the whole board",
              "visibility": f"all corners {margin:.0%} inside the image, tilt <= "
                            f"{max_tilt_deg:g} deg, board >= {min_size:g} of the image "
                            "diagonal", "noise": f"{sigma:g} px", "criterion": criterion,
              "board distance": f"{d * 1e3:.0f} mm at the centre", "seed": str(seed)}
    return CameraPlan(design.q, Xp, Zp, chosen, design, sp, sr,
                      dict(zip(problem.names, std.tolist(), strict=True)), rp, rr, why,
                      len(q), len(qv), inputs)


def write_camera_poses(path: str, robot: Robot, q: ArrayLike, angle_unit: str = "deg",
                       length_unit: str = "mm", comments: Sequence[str] = ()) -> list[str]:
    """Write the planned poses as the joints CSV of ``kincal import images --joints``:
    ``image`` (``pose_01.png`` ...: name the images so), then one column per joint with
    its unit (``{joint}_{unit}``), ``#`` comment lines first; atomically.  Returns the
    image names."""
    from kincal.io import atomic_write_text
    from kincal.measure.files import joint_columns

    Q = np.atleast_2d(np.asarray(q, dtype=float))
    cols = joint_columns(robot, Q.shape[1], angle_unit, length_unit)
    names = [f"pose_{k + 1:02d}.png" for k in range(len(Q))]
    lines = [f"# {c}" for c in comments] + [",".join(["image"] + [n for n, _ in cols])]
    lines += [",".join([n] + [f"{v * f:.6f}" for v, (_, f) in zip(row, cols, strict=True)])
              for n, row in zip(names, Q, strict=True)]
    atomic_write_text(path, "\n".join(lines) + "\n")
    return names
