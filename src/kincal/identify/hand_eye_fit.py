"""Hand-eye calibration of a camera on the flange: closed-form start, joint fit, quality.

From a hand-camera measurement block (:class:`~kincal.measure.instruments.camera.
HandCameraMeasurement`, one row per board corner, undistorted pixels) and the image each
row came from:

1. **Held-out images**: every ``k``-th image in name order, ``k = round(1 / holdout)``
   (starting at the ``k // 2``-th), is kept aside; the rest is the training set.  The
   choice depends on the image names only, never on the order of the rows.
2. **Rotations**: :func:`~kincal.identify.hand_eye.check_rotations` refuses, naming the
   axes, when the training poses turn the flange less than ``min_rotation_deg`` about
   two axes.
3. **Start**: the board's pose in every training image
   (:func:`~kincal.measure.camera_board.board_pose`), then the order-free closed form
   :func:`~kincal.identify.hand_eye.hand_eye`: ``X`` (camera in the robot's tool frame)
   and ``Z`` (board in the base frame).
4. **Joint fit** with :func:`~kincal.identify.solver.calibrate`: the robot's tool frame
   becomes the camera (``tool <- tool X``), the board pose is the block's
   ``{name}.target.*``; estimated: ``tool.*``, the board pose and any robot parameters
   named in ``free`` that the images identify (of a dependent group the hand-eye and the
   board are kept, e.g. ``tool.rz`` rather than the last joint's offset); minimised: the
   whitened reprojection errors ``(uv_pred - uv_obs) / sigma`` [1].
5. **Quality**: the hand-eye's standard errors from the fit's covariance,
   ``sigma_p = sqrt(trace Cov(tool.x, y, z))`` [m] and ``sigma_r = sqrt(trace(J Cov J^T))``
   [rad], ``J`` the derivative of the rotation vector by ``(rz, ry, rx)``.  The
   covariance takes every corner as an independent look; an error the model does not
   have (joint readings off the pose the image was taken at, a link error not fitted)
   moves all corners of an image together, and on the real Franka set the covariance
   was 9 times smaller than the leave-one-out spread.  So the same figures are computed
   from the image-clustered covariance (:func:`image_clustered_covariance`, the
   sandwich with the images as the independent units), ``sigma_p,img``, ``sigma_r,img``,
   and the **expected error** is ``sqrt(sigma^2 + floor^2)`` with the **unmodelled
   floor** ``floor^2 = max(0, sigma_img^2 - sigma^2)``, i.e. the larger of the two.
   Monte Carlo (12 images, 0.1 deg of unmodelled joint error per joint and image): the
   true error's RMS is 1.0-1.1 times the expected error, 4.7-5.4 times the covariance's.
   On the held-out images: the reprojection RMS [px] with the fitted robot and board,
   and the 3-D error it implies at the board, ``|duv| z / f`` [m] per corner (``z`` its
   depth in the camera).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.identify.hand_eye import HandEye, average_pose, check_rotations, hand_eye
from kincal.identify.result import CalibrationResult
from kincal.identify.solver import calibrate
from kincal.measure.camera_board import board_pose
from kincal.measure.instruments.camera import HandCameraMeasurement
from kincal.robots.chain import Robot
from kincal.spatial import frame_from_matrix, inverse, log_so3, matrix_from_frame

Array = NDArray[np.float64]

TOOL = tuple(f"tool.{f}" for f in ("x", "y", "z", "rz", "ry", "rx"))

__all__ = ["HandEyeFit", "split_images", "fit_hand_camera", "closed_form_leave_one_out",
           "LeaveOneOut", "leave_one_out", "image_clustered_covariance",
           "clustered_covariance"]


def split_images(labels: Sequence[str], holdout: float) -> tuple[list[str], list[str]]:
    """``(training, held out)`` image names (module docstring, step 1)."""
    names = sorted(set(labels))
    if not 0.0 <= holdout < 1.0:
        raise KincalError(f"--holdout {holdout:g}: use a fraction in [0, 1)")
    if holdout == 0.0 or len(names) < 4:
        return names, []
    k = max(2, int(round(1.0 / holdout)))
    held = names[k // 2::k]
    return [n for n in names if n not in held], held


def _subset(block: HandCameraMeasurement, rows: NDArray[np.bool_]) -> HandCameraMeasurement:
    return HandCameraMeasurement(block.name, block.q[rows], block.s[rows], block.obs[rows],
                                 block.sigma[rows], block.intrinsics)


@dataclass
class HandEyeFit:
    """The outcome of :func:`fit_hand_camera` (lengths in m, angles in rad unless named).

    Attributes:
        start: the closed-form solution (``X`` in the nominal tool frame).
        X: the fitted camera pose in the nominal robot's tool frame (4x4).
        board: the fitted board pose in the base frame (4x4).
        std_position, std_rotation: the covariance's 3-D error of the camera position
            [m] and direction [rad] (module docstring, step 5).
        robust_position, robust_rotation: the same from the image-clustered covariance;
            ``expected_position`` / ``expected_rotation`` combine them.
        result: the joint fit.
        training, held_out: image names.
        train_rms_px, held_rms_px: reprojection RMS [px] (``nan`` without held-out images).
        held_rms_3d: RMS 3-D error at the board implied by the held-out pixels [m].
        held_per_image: ``{image: RMS px}`` on the held-out images.
        rotation_deg: RMS rotation of the flange about its principal axes [deg].
    """

    start: HandEye
    X: Array
    board: Array
    std_position: float
    std_rotation: float
    result: CalibrationResult
    training: list[str]
    held_out: list[str]
    train_rms_px: float
    held_rms_px: float
    held_rms_3d: float
    rotation_deg: Array
    held_per_image: dict[str, float] = field(default_factory=dict)
    robust_position: float = float("nan")
    robust_rotation: float = float("nan")

    @property
    def expected_position(self) -> float:
        """Expected 3-D error of the camera position [m]: ``sqrt(max(sigma_p^2,
        sigma_p,img^2))``, the covariance's figure plus the unmodelled floor."""
        return float(np.hypot(self.std_position, self.floor_position))

    @property
    def expected_rotation(self) -> float:
        """Expected error of the camera direction [rad] (as :attr:`expected_position`)."""
        return float(np.hypot(self.std_rotation, self.floor_rotation))

    @property
    def floor_position(self) -> float:
        """Unmodelled floor of the camera position [m]: ``sqrt(max(0, sigma_p,img^2 -
        sigma_p^2))`` (0 when the image-clustered figure is not there)."""
        return _floor(self.robust_position, self.std_position)

    @property
    def floor_rotation(self) -> float:
        """Unmodelled floor of the camera direction [rad]."""
        return _floor(self.robust_rotation, self.std_rotation)


def _floor(robust: float, std: float) -> float:
    return float(np.sqrt(max(robust**2 - std**2, 0.0))) if np.isfinite(robust) else 0.0


def _per_image_poses(block: HandCameraMeasurement, labels: NDArray[np.str_],
                     names: Sequence[str]) -> Array:
    out = []
    for n in names:
        r = labels == n
        out.append(board_pose(block.s[r], block.obs[r], block.intrinsics)[0])
    return np.array(out)


def _rotation_std(frame: Array, cov: Array) -> float:
    """``sqrt(trace(J Cov J^T))`` [rad], ``J = d log(R(theta) R0^T) / d theta`` at the
    frame ``(rz, ry, rx)`` (central differences, step 1e-6 rad)."""
    R0 = matrix_from_frame(frame)[:3, :3]
    J = np.zeros((3, 3))
    for k in range(3):
        d = np.zeros(6)
        d[3 + k] = 1e-6
        J[:, k] = (log_so3(matrix_from_frame(frame + d)[:3, :3] @ R0.T)
                   - log_so3(matrix_from_frame(frame - d)[:3, :3] @ R0.T)) / 2e-6
    return float(np.sqrt(max(np.trace(J @ cov @ J.T), 0.0)))


def _reprojection(block: HandCameraMeasurement, robot: Robot, target: Array
                  ) -> tuple[Array, Array]:
    """Pixel error per row [px] and the 3-D error it implies at the point [m]."""
    r = block.evaluate(robot, target, jacobian=False)[0].reshape(-1, 2) * block.sigma[:, None]
    T = robot.fk(block.q)
    w = block.s @ matrix_from_frame(target)[:3, :3].T + matrix_from_frame(target)[:3, 3]
    depth = np.einsum("ni,ni->n", T[:, :3, 2], w - T[:, :3, 3])
    e = np.hypot(r[:, 0], r[:, 1])
    f = 0.5 * (block.K[:, 0] + block.K[:, 1])
    return e, e * depth / f


def image_clustered_covariance(result: CalibrationResult, images: Sequence[str]) -> Array:
    """Covariance of the estimated parameters that trusts the images, not the corners
    (module docstring, step 5): the sandwich ``A (sum_i J_i^T u_i u_i^T J_i) A`` with
    ``A = (J^T W J)^-1`` and, per image ``i``, its rows of the whitened Jacobian ``J_i``
    and residuals ``r_i``, ``u_i = (I - H_ii)^-1/2 r_i`` (``H_ii = J_i A J_i^T``: the
    image's block of the hat matrix; the correction for what the fit itself absorbed).

    ``images``: the image of every row of the fit's (single) camera block.  Returns the
    (p, p) covariance over ``result.estimated`` [m^2, rad^2]."""
    prob = result.problem
    if len(prob.blocks) != 1:
        raise KincalError("the image-clustered covariance needs one camera block")
    robot, extra = prob.split(result.theta)
    r, Jr, Je = prob.blocks[0].evaluate(robot, extra[0], jacobian=True)
    if Jr is None or Je is None:
        raise KincalError("the camera block returned no Jacobian")
    J = np.hstack([Jr, Je])[:, [prob.names.index(n) for n in result.estimated]]
    w = np.sqrt(np.asarray(result.weights, dtype=float).reshape(-1))
    return clustered_covariance(J * w[:, None], r * w, np.repeat(np.asarray(list(images)), 2))


def clustered_covariance(J: Array, r: Array, owner: Sequence[str] | NDArray[np.str_]) -> Array:
    """The sandwich ``A (sum_i J_i^T u_i u_i^T J_i) A``, ``A = (J^T J)^-1``, over the
    clusters ``owner`` (the image of every residual), ``u_i = (I - H_ii)^-1/2 r_i`` with
    ``H_ii = J_i A J_i^T`` (:func:`image_clustered_covariance`); ``J`` (M, p) and ``r``
    (M,) whitened.  Returns (p, p)."""
    A = np.linalg.pinv(J.T @ J)
    owner = np.asarray(owner)
    if len(owner) != len(r):
        raise KincalError(f"{len(owner) // 2} image labels for {len(r) // 2} rows")
    meat = np.zeros_like(A)
    for name in np.unique(owner):
        rows = owner == name
        Ji = J[rows]
        lam, V = np.linalg.eigh(np.eye(len(Ji)) - Ji @ A @ Ji.T)
        ui = Ji.T @ (V @ ((V.T @ r[rows]) / np.sqrt(np.clip(lam, 1e-6, None))))
        meat += np.outer(ui, ui)
    return np.asarray(A @ meat @ A, dtype=float)


def fit_hand_camera(robot: Robot, block: HandCameraMeasurement, images: Sequence[str],
                    holdout: float = 0.25, free: Sequence[str] = (),
                    min_rotation_deg: float = 5.0, held_out: Sequence[str] | None = None
                    ) -> HandEyeFit:
    """Hand-eye (and robot parameters ``free``) from a hand camera (module docstring).

    Args:
        robot: the nominal robot; its tool frame is the flange the camera sits on.
        block: the camera rows (undistorted pixels, board points).
        images: the image of every row (N,).
        holdout: fraction of images kept aside.
        free: robot parameter names / patterns fitted with the hand-eye (e.g.
            ``"theta_offset*"``); parameters the images cannot identify are held.
        min_rotation_deg: the refusal threshold of the flange's rotation.
        held_out: the images to keep aside (instead of ``holdout``'s choice).
    """
    labels = np.asarray(list(images))
    if len(labels) != block.q.shape[0]:
        raise KincalError(f"{len(labels)} image labels for {block.q.shape[0]} rows")
    train, held = split_images(list(labels), holdout)
    if held_out is not None:
        held = sorted(set(held_out))
        train = [n for n in sorted(set(labels.tolist())) if n not in held]
    if len(train) < 3:
        raise KincalError(f"{len(train)} training images: a hand-eye needs 3 at least "
                          "(better 10 or more)")
    first = np.array([np.flatnonzero(labels == n)[0] for n in train])
    A = robot.fk(block.q[first])
    rot = check_rotations(A, min_rotation_deg)
    start = hand_eye(A, _per_image_poses(block, labels, train))
    tool0 = matrix_from_frame(robot.frame_parameters("tool"))
    robot0 = robot.with_params(dict(zip(TOOL, frame_from_matrix(tool0 @ start.X).tolist(),
                                        strict=True)))
    tr = _subset(block, np.isin(labels, train))
    target_names = tr.parameters().names
    initial = dict(zip(target_names, frame_from_matrix(start.Z).tolist(), strict=True))
    res = calibrate(robot0, [tr], free=[*TOOL, f"{block.name}.target.*", *free],
                    initial=initial, prefer=[*TOOL, f"{block.name}.target.*"])
    missing = [n for n in TOOL if n not in res.estimated]
    if missing:
        raise KincalError(f"the images cannot identify the hand-eye ({', '.join(missing)} "
                          "held): add poses that tilt the camera about other axes")
    p = res.params
    tool = np.array([p[n] for n in TOOL])
    target = np.array([p[n] for n in target_names])
    k = [res.estimated.index(n) for n in TOOL]
    cov = res.covariance[np.ix_(k, k)]
    e_tr = _reprojection(tr, res.robot, target)[0]
    clus = image_clustered_covariance(res, labels[np.isin(labels, train)].tolist())[
        np.ix_(k, k)]
    out = HandEyeFit(start, inverse(tool0) @ matrix_from_frame(tool),
                     matrix_from_frame(target), float(np.sqrt(np.trace(cov[:3, :3]))),
                     _rotation_std(tool, cov[3:, 3:]), res, train, held,
                     float(np.sqrt(np.mean(e_tr**2))), float("nan"), float("nan"), rot)
    out.robust_position = float(np.sqrt(np.trace(clus[:3, :3])))
    out.robust_rotation = _rotation_std(tool, clus[3:, 3:])
    if held:
        rows = np.isin(labels, held)
        e, e3 = _reprojection(_subset(block, rows), res.robot, target)
        out.held_rms_px = float(np.sqrt(np.mean(e**2)))
        out.held_rms_3d = float(np.sqrt(np.mean(e3**2)))
        lab = labels[rows]
        out.held_per_image = {n: float(np.sqrt(np.mean(e[lab == n] ** 2))) for n in held}
    return out


def closed_form_leave_one_out(robot_poses: Array, points: Sequence[Array],
                              uv: Sequence[Array], intrinsics: Sequence[float],
                              mount: str = "hand") -> tuple[HandEye, Array]:
    """The closed form on every image, and each image predicted by the closed form of the
    others: for a few images (an eye-to-hand set with flange poses and no joints).

    Image ``i``'s board pose is predicted as ``B_i = X^-1 A_i^-1 Z`` (eye-in-hand) or
    ``X^-1 A_i Z`` (eye-to-hand) from the solution without image ``i``, its corners
    ``points[i]`` (n, 3) [m] projected with the pinhole ``intrinsics`` and compared with
    the undistorted pixels ``uv[i]`` (n, 2).  Returns the solution on all images and the
    held-out RMS reprojection error of every image [px].
    """
    A = np.asarray(robot_poses, dtype=float)
    K = np.asarray(intrinsics, dtype=float)
    B = np.array([board_pose(p, u, K)[0] for p, u in zip(points, uv, strict=True)])
    every = hand_eye(A, B, mount)
    rms = np.zeros(len(A))
    for i in range(len(A)):
        keep = np.arange(len(A)) != i
        he = hand_eye(A[keep], B[keep], mount)
        Ai = A[i] if mount == "fixed" else inverse(A[i])
        Bi = inverse(he.X) @ Ai @ he.Z
        x = points[i] @ Bi[:3, :3].T + Bi[:3, 3]
        pred = np.column_stack([K[0] * x[:, 0] / x[:, 2] + K[2], K[1] * x[:, 1] / x[:, 2] + K[3]])
        rms[i] = float(np.sqrt(np.mean(np.sum((pred - uv[i]) ** 2, axis=1))))
    return every, rms


@dataclass
class LeaveOneOut:
    """Every image held out once: its reprojection RMS [px] and 3-D error [m] under the
    fit of the others, and the spread of the hand-eye over those fits (RMS distance of the
    camera position [m] and angle of its rotation [rad] from their mean), a figure that
    does not come from the covariance."""

    images: list[str]
    rms_px: Array
    rms_3d: Array
    position_spread: float
    rotation_spread: float


def leave_one_out(robot: Robot, block: HandCameraMeasurement, images: Sequence[str],
                  free: Sequence[str] = (), min_rotation_deg: float = 5.0) -> LeaveOneOut:
    """:func:`fit_hand_camera` once per image with that image held out.  The spread of
    ``N`` leave-one-out estimates is ``1 / (N - 1)`` of the estimate's jackknife spread:
    the jackknife standard error is ``sqrt((N - 1) / N sum |x_i - mean|^2)``, reported
    here as ``position_spread`` and ``rotation_spread``."""
    names = sorted(set(images))
    fits = [fit_hand_camera(robot, block, images, 0.0, free, min_rotation_deg, [n])
            for n in names]
    X = np.array([f.X for f in fits])
    t = X[:, :3, 3]
    n = len(names)
    pos = float(np.sqrt((n - 1) / n * np.sum((t - t.mean(0)) ** 2)))
    R = average_pose(X)[:3, :3]
    ang = np.linalg.norm(log_so3(X[:, :3, :3] @ R.T), axis=1)
    rot = float(np.sqrt((n - 1) / n * np.sum(ang**2)))
    return LeaveOneOut(names, np.array([f.held_rms_px for f in fits]),
                       np.array([f.held_rms_3d for f in fits]), pos, rot)
