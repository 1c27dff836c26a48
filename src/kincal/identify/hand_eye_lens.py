"""Hand-eye and camera intrinsics in one fit, from the raw (distorted) board pixels.

Every image ``i`` gives the flange pose ``A_i`` (4x4, base -> flange, from the robot's
joints or a pose file) and the detected corners: board points ``P_ij`` (board frame, z = 0)
[m] and their raw pixels ``uv_ij`` [px].  The board's pose in the camera is

* eye-in-hand (camera on the flange, board fixed): ``B_i = X^-1 A_i^-1 Z``, ``X`` the
  camera in the flange frame, ``Z`` the board in the base frame;
* eye-to-hand (camera fixed, board on the flange): ``B_i = X^-1 A_i Z``, ``X`` the camera
  in the base frame, ``Z`` the board in the flange frame.

A camera-frame point ``x = B_i P`` projects with OpenCV's pinhole + radial-tangential model
(``lens = fx fy cx cy k1 k2 p1 p2 k3``)::

    a = x1 / x3,  b = x2 / x3,  r^2 = a^2 + b^2,  g = 1 + k1 r^2 + k2 r^4 + k3 r^6
    a' = a g + 2 p1 a b + p2 (r^2 + 2 a^2),   b' = b g + p1 (r^2 + 2 b^2) + 2 p2 a b
    u = fx a' + cx,   v = fy b' + cy                                              [px]

or, ``model="fisheye"``, with OpenCV's equidistant (Kannala-Brandt) model
(``lens = fx fy cx cy k1 k2 k3 k4``, :mod:`~kincal.identify.lens_fisheye`)::

    theta = atan2(|x1, x2|, x3),   theta_d = theta (1 + k1 theta^2 + .. + k4 theta^8)
    u = fx theta_d x1 / |x1, x2| + cx,   v = fy theta_d x2 / |x1, x2| + cy         [px]

The fit (:func:`fit_board_camera`) minimises ``sum |uv_pred - uv| ^ 2 / sigma^2`` over
``X``, ``Z`` and the intrinsics named in ``fit_lens`` by Levenberg-Marquardt (Jacobian by
central differences: 21 parameters; the fisheye model's analytic, :func:`_fisheye_jacobian`,
the robot parameters' by central differences), from a closed-form start: the intrinsics given or
estimated beforehand (OpenCV's ``calibrateCamera``, or without distortion as the ABB
set's), the pixels undistorted with them (:func:`undistort_pixels`), the board pose per
image (:func:`~kincal.measure.camera_board.board_pose`) and the order-free hand-eye
(:func:`~kincal.identify.hand_eye.hand_eye`).  Poses are updated as ``t <- t + dv``,
``R <- exp(dw) R``, so the position and rotation blocks of the covariance are those of
the camera's position [m] and of a small rotation vector [rad].

Quality, as :mod:`~kincal.identify.hand_eye_fit`: the covariance ``sigma0^2 (J^T J)^-1``,
the image-clustered covariance (the images as the independent units), the expected error
``sqrt(sigma^2 + floor^2)`` with the unmodelled floor ``max(0, sigma_img^2 - sigma^2)``,
and the held-out images' reprojection RMS [px] (:func:`calibrate_board_camera`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import IdentifiabilityError, KincalError
from kincal.identify.hand_eye import HandEye, average_pose, check_rotations, hand_eye
from kincal.identify.hand_eye_fit import (
    LeaveOneOut,
    clustered_covariance,
    fit_hand_camera,
    split_images,
)
from kincal.identify.hand_eye_fixed import fixed_camera_robot_start
from kincal.identify.lens_fisheye import (
    FISHEYE,
    fisheye_jacobian,
    project_fisheye,
    undistort_fisheye,
)
from kincal.measure.camera_board import board_pose
from kincal.measure.camera_images import Intrinsics
from kincal.measure.instruments.camera import HandCameraMeasurement
from kincal.robots.chain import Robot
from kincal.spatial import exp_so3, inverse, log_so3

Array = NDArray[np.float64]

LENS = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
POSE = ("x", "y", "z", "wx", "wy", "wz")
#: The lens models and their intrinsics: OpenCV's radial-tangential (ROS ``plumb_bob``)
#: and fisheye (ROS ``equidistant``).
MODELS = {"radtan": LENS, "fisheye": FISHEYE}

__all__ = ["LENS", "FISHEYE", "MODELS", "LensFit", "project_lens", "project_model",
           "undistort_pixels", "undistort_model", "fit_board_camera",
           "calibrate_board_camera", "lens_leave_one_out", "lens_start"]


def project_lens(x: Array, lens: ArrayLike) -> Array:
    """Raw pixels (n, 2) of camera-frame points ``x`` (n, 3) [m] (module docstring)."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (float(v) for v in np.asarray(lens).reshape(9))
    a, b = x[:, 0] / x[:, 2], x[:, 1] / x[:, 2]
    r2 = a * a + b * b
    g = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    ad = a * g + 2.0 * p1 * a * b + p2 * (r2 + 2.0 * a * a)
    bd = b * g + p1 * (r2 + 2.0 * b * b) + 2.0 * p2 * a * b
    return np.column_stack([fx * ad + cx, fy * bd + cy])


def undistort_pixels(uv: Array, lens: ArrayLike, iterations: int = 50) -> Array:
    """The pinhole pixels ``(fx a + cx, fy b + cy)`` of raw pixels ``uv`` (n, 2): ``(a, b)``
    by the fixed-point iteration ``(a, b) <- ((a', b') - tangential(a, b)) / g(a, b)``
    (OpenCV's), converged to 1e-12 of the normalised coordinates or ``iterations``."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (float(v) for v in np.asarray(lens).reshape(9))
    ad, bd = (uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy
    a, b = ad.copy(), bd.copy()
    for _ in range(iterations):
        r2 = a * a + b * b
        g = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        na = (ad - 2.0 * p1 * a * b - p2 * (r2 + 2.0 * a * a)) / g
        nb = (bd - p1 * (r2 + 2.0 * b * b) - 2.0 * p2 * a * b) / g
        done = max(float(np.abs(na - a).max(initial=0.0)),
                   float(np.abs(nb - b).max(initial=0.0))) < 1e-12
        a, b = na, nb
        if done:
            break
    return np.column_stack([fx * a + cx, fy * b + cy])


def _model(model: str) -> tuple[str, ...]:
    if model not in MODELS:
        raise KincalError(f"lens model {model!r}: use {' or '.join(MODELS)}")
    return MODELS[model]


def project_model(x: Array, lens: ArrayLike, model: str = "radtan") -> Array:
    """Raw pixels (n, 2) [px] of camera-frame points ``x`` (n, 3) [m] through ``model``."""
    _model(model)
    return project_fisheye(x, lens) if model == "fisheye" else project_lens(x, lens)


def undistort_model(uv: Array, lens: ArrayLike, model: str = "radtan") -> Array:
    """The pinhole pixels (n, 2) [px] of the rays of raw pixels ``uv`` through ``model``."""
    _model(model)
    return undistort_fisheye(uv, lens) if model == "fisheye" else undistort_pixels(uv, lens)


def lens_start(intr: Intrinsics, lens: str) -> tuple[str, Array, tuple[str, ...]]:
    """The lens model (``"radtan"`` or ``"fisheye"``: the start intrinsics' own), the start
    vector and the intrinsics fitted for the option ``--lens`` (``all`` or ``fisheye``:
    every one, ``pinhole``: fx fy cx cy, ``none``); ``--lens fisheye`` with
    radial-tangential start intrinsics is refused in one line."""
    fish = intr.model == "equidistant"
    if lens == "fisheye" and not fish:
        raise KincalError(f"--lens fisheye: the start intrinsics ({intr.source}) are a "
                          f"{intr.model} lens; give equidistant ones (distortion_model: "
                          "equidistant) or none (estimated by cv2.fisheye.calibrate)")
    names = FISHEYE if fish else LENS
    fitted = {"all": names, "fisheye": names, "pinhole": names[:4], "none": ()}.get(lens)
    if fitted is None:
        raise KincalError(f"--lens {lens}: use all, pinhole, none or fisheye")
    n = len(names) - 4
    return ("fisheye" if fish else "radtan",
            np.r_[intr.pinhole, (list(intr.dist) + [0.0] * n)[:n]], tuple(fitted))


def _chain(A: Array, mount: str) -> Array:
    """``C_i`` with ``B_i = X^-1 C_i Z``: ``A_i^-1`` (hand) or ``A_i`` (fixed)."""
    if mount == "hand":
        return inverse(A)
    if mount == "fixed":
        return A
    raise KincalError(f"mount={mount!r}: use 'hand' or 'fixed'")


def _moved(T: Array, d: Array) -> Array:
    out = T.copy()
    out[:3, 3] = T[:3, 3] + d[:3]
    out[:3, :3] = exp_so3(d[3:]) @ T[:3, :3]
    return out


@dataclass
class LensFit:
    """The outcome of :func:`fit_board_camera` (lengths in m, angles in rad).

    Attributes:
        X, Z: the hand-eye and the board (module docstring), 4x4.
        lens: the intrinsics ``lens_names`` (``fx fy cx cy k1 k2 p1 p2 k3`` [px, 1], or
            the fisheye's ``fx fy cx cy k1 k2 k3 k4``).
        lens_std: their standard errors from the covariance (0 where not fitted).
        names: the fitted parameters (``X.x .. X.wz, Z.x .. Z.wz``, then the intrinsics).
        covariance, clustered: ``sigma0^2 (J^T J)^-1`` and the image-clustered one over
            ``names``.
        sigma0: the noise scale (RMS whitened residual, ``M - p`` degrees of freedom).
        std_position, std_rotation, robust_position, robust_rotation: the camera's 3-D
            position [m] and direction [rad] error from each covariance.
        training, held_out: image names; train_rms_px, held_rms_px: reprojection RMS [px].
        held_per_image: ``{image: RMS px}`` on the held-out images; held_rms_3d: the
            3-D error their pixels imply at the board, ``|duv| z / f`` [m] per corner.
        robot: ``{name: (value, standard error)}`` of the robot parameters fitted.
        start: the closed-form hand-eye; rotation_deg: the flange's rotation spread.
        held: ``{name: reason}`` of the robot parameters asked for and held at nominal
            (eye-to-hand: :mod:`~kincal.identify.hand_eye_fixed`).
    """

    X: Array
    Z: Array
    lens: Array
    lens_std: Array
    names: list[str]
    covariance: Array
    clustered: Array
    sigma0: float
    std_position: float
    std_rotation: float
    robust_position: float
    robust_rotation: float
    training: list[str] = field(default_factory=list)
    held_out: list[str] = field(default_factory=list)
    train_rms_px: float = float("nan")
    held_rms_px: float = float("nan")
    held_per_image: dict[str, float] = field(default_factory=dict)
    held_rms_3d: float = float("nan")
    start: HandEye | None = None
    robot: dict[str, tuple[float, float]] = field(default_factory=dict)
    rotation_deg: Array = field(default_factory=lambda: np.zeros(3))
    model: str = "radtan"
    lens_names: tuple[str, ...] = LENS
    held: dict[str, str] = field(default_factory=dict)

    @property
    def floor_position(self) -> float:
        """``sqrt(max(0, sigma_p,img^2 - sigma_p^2))`` [m]: the unmodelled floor."""
        return float(np.sqrt(max(self.robust_position**2 - self.std_position**2, 0.0)))

    @property
    def floor_rotation(self) -> float:
        """The unmodelled floor of the camera direction [rad]."""
        return float(np.sqrt(max(self.robust_rotation**2 - self.std_rotation**2, 0.0)))

    @property
    def expected_position(self) -> float:
        """Expected 3-D error of the camera position [m]: covariance plus floor."""
        return float(max(self.std_position, self.robust_position))

    @property
    def expected_rotation(self) -> float:
        """Expected error of the camera direction [rad]: covariance plus floor."""
        return float(max(self.std_rotation, self.robust_rotation))


def _residuals(C: Sequence[Array], points: Sequence[Array], uv: Sequence[Array], X: Array,
               Z: Array, lens: Array, model: str = "radtan") -> Array:
    Xi = inverse(X)
    out = []
    for Ci, P, obs in zip(C, points, uv, strict=True):
        B = Xi @ Ci @ Z
        out.append((project_model(P @ B[:3, :3].T + B[:3, 3], lens, model) - obs).reshape(-1))
    return np.concatenate(out)


def _skew(v: Array) -> Array:
    """``[v]_x`` of every row of ``v`` (n, 3): (n, 3, 3)."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    return S - S.transpose(0, 2, 1)


def _fisheye_jacobian(C: Sequence[Array], points: Sequence[Array], X: Array, Z: Array,
                      lens: Array, lk: Sequence[int]) -> Array:
    """``d uv / d (X.x .. X.wz, Z.x .. Z.wz, lens[lk])`` (2 n, 12 + len(lk)) [px per m,
    rad, unit] of the fisheye residuals, analytic.  With ``y = C Z P`` and ``u = y - t_X``
    the camera point is ``x = R_X^T u``; the updates ``t <- t + dv``, ``R <- exp(dw) R``
    give ``dx/dX.v = -R_X^T``, ``dx/dX.w = R_X^T [u]_x``, ``dx/dZ.v = R_X^T R_C`` and
    ``dx/dZ.w = -R_X^T R_C [R_Z P]_x``, chained with :func:`fisheye_jacobian`."""
    RX, tX = X[:3, :3], X[:3, 3]
    out = []
    for Ci, P in zip(C, points, strict=True):
        zP = P @ Z[:3, :3].T
        u = (zP + Z[:3, 3]) @ Ci[:3, :3].T + Ci[:3, 3] - tX
        jx, jl = fisheye_jacobian(u @ RX, lens)
        M = RX.T @ Ci[:3, :3]
        dx = np.concatenate([np.broadcast_to(-RX.T, (len(P), 3, 3)), RX.T @ _skew(u),
                             np.broadcast_to(M, (len(P), 3, 3)), -M @ _skew(zP)], axis=2)
        out.append(np.concatenate([jx @ dx, jl[:, :, list(lk)]], axis=2).reshape(-1, 12 + len(lk)))
    return np.concatenate(out)


def _refuse_if_singular(J: Array, names: Sequence[str]) -> None:
    """One line naming the parameters the images cannot tell apart (a near-null direction
    of the column-scaled ``J^T J``, condition above 1e12)."""
    s = np.linalg.norm(J, axis=0)
    if np.any(s == 0):
        raise IdentifiabilityError(f"the images do not see {names[int(np.argmin(s))]}")
    lam, V = np.linalg.eigh((J / s).T @ (J / s))
    if lam[0] < 1e-12 * lam[-1]:
        top = np.argsort(-np.abs(V[:, 0]))[:3]
        raise IdentifiabilityError(
            "the images cannot tell apart " + ", ".join(names[k] for k in top)
            + ": add images with the board nearer the image corners and tilted (or give "
            "the intrinsics and fit fewer)")


def fit_board_camera(robot_poses: Array, points: Sequence[Array], uv: Sequence[Array],
                     images: Sequence[str], lens0: ArrayLike, X0: Array, Z0: Array,
                     mount: str = "hand", fit_lens: Sequence[str] | None = None,
                     sigma: float = 0.5, iterations: int = 100,
                     kinematics: Callable[[Array], Array] | None = None,
                     robot_names: Sequence[str] = (), robot_values: ArrayLike = (),
                     model: str = "radtan") -> LensFit:
    """Levenberg-Marquardt over ``X``, ``Z`` and the intrinsics ``fit_lens`` (module
    docstring) from ``(X0, Z0, lens0)``; one entry of ``points`` (n_i, 3) [m] and raw
    ``uv`` (n_i, 2) [px] per image, ``sigma`` the stated corner noise [px].

    With ``kinematics`` (robot parameter values -> the flange poses (N, 4, 4) of the
    images), the robot parameters ``robot_names`` are fitted too, from ``robot_values``
    (``robot_poses`` is then unused).  ``model``: ``"radtan"`` or ``"fisheye"``
    (``lens0`` and ``fit_lens`` its intrinsics, default all of them)."""
    lens_names = _model(model)
    fit_lens = lens_names if fit_lens is None else fit_lens
    unknown = [n for n in fit_lens if n not in lens_names]
    if unknown:
        raise KincalError(f"{unknown[0]!r} is not an intrinsic of the {model} lens; use "
                          f"{', '.join(lens_names)}")
    lk = [lens_names.index(n) for n in fit_lens]
    rv = np.asarray(robot_values, dtype=float).reshape(-1)
    nr = len(rv) if kinematics is not None else 0
    names = ([f"X.{n}" for n in POSE] + [f"Z.{n}" for n in POSE] + list(fit_lens)
             + list(robot_names)[:nr])
    steps = np.r_[np.full(12, 1e-7), [1e-4 if k < 4 else 1e-7 for k in lk], np.full(nr, 1e-7)]
    X, Z, lens = np.array(X0, dtype=float), np.array(Z0, dtype=float), np.array(lens0, float)
    C0 = list(_chain(np.asarray(robot_poses, dtype=float), mount)) if nr == 0 else []
    nl = 12 + len(lk)

    def moved(p: Array) -> tuple[Array, Array, Array, Array]:
        ln = lens.copy()
        ln[lk] += p[12:nl]
        return _moved(X, p[:6]), _moved(Z, p[6:12]), ln, rv + p[nl:]

    def res(p: Array) -> Array:
        Xp, Zp, ln, th = moved(p)
        C = list(_chain(kinematics(th), mount)) if kinematics is not None and nr else C0
        return _residuals(C, points, uv, Xp, Zp, ln, model) / sigma

    def jac() -> Array:
        cols = []
        if model == "fisheye":
            C = list(_chain(kinematics(rv), mount)) if kinematics is not None and nr else C0
            cols = list(_fisheye_jacobian(C, points, X, Z, lens, lk).T / sigma)
        for k, h in enumerate(steps[len(cols):], start=len(cols)):
            d = np.zeros(len(names))
            d[k] = h
            cols.append((res(d) - res(-d)) / (2.0 * h))
        return np.column_stack(cols)

    r = res(np.zeros(len(names)))
    lam = 1e-3
    for _ in range(iterations):
        J = jac()
        H, g = J.T @ J, J.T @ r
        cost = float(r @ r)
        while True:
            step = np.asarray(-np.linalg.solve(H + lam * np.diag(np.diag(H)), g), dtype=float)
            r_new = res(step)
            if float(r_new @ r_new) <= cost:
                X, Z, lens, rv = moved(step)
                r, lam = r_new, max(lam / 10.0, 1e-12)
                break
            lam *= 10.0
            if lam > 1e12:
                break
        if lam > 1e12 or cost - float(r @ r) <= 1e-12 * cost:
            break
    J = jac()
    _refuse_if_singular(J, names)
    Ainv = np.asarray(np.linalg.inv(J.T @ J), dtype=float)
    dof = max(len(r) - len(names), 1)
    sigma0 = float(np.sqrt(r @ r / dof))
    cov: Array = sigma0**2 * Ainv
    owner = np.concatenate([np.full(2 * len(P), n, dtype=object)
                            for n, P in zip(images, points, strict=True)])
    clus = np.asarray(clustered_covariance(J, r, owner.astype(str)), dtype=float)
    std = np.zeros(len(lens_names))
    std[lk] = np.sqrt(np.diag(cov)[12:nl])

    def tr(M: Array, s: slice) -> float:
        return float(np.sqrt(max(np.trace(M[s, s]), 0.0)))

    e = np.hypot(*(r * sigma).reshape(-1, 2).T)
    return LensFit(X, Z, lens, std, names, cov, clus, sigma0, tr(cov, slice(0, 3)),
                   tr(cov, slice(3, 6)), tr(clus, slice(0, 3)), tr(clus, slice(3, 6)),
                   sorted(set(images)), train_rms_px=float(np.sqrt(np.mean(e**2))),
                   robot={n: (float(v), float(np.sqrt(cov[nl + k, nl + k])))
                          for k, (n, v) in enumerate(zip(names[nl:], rv, strict=True))},
                   model=model, lens_names=lens_names)


def calibrate_board_camera(robot_poses: Array, points: Sequence[Array], uv: Sequence[Array],
                           images: Sequence[str], lens0: ArrayLike, mount: str = "hand",
                           holdout: float = 0.25, fit_lens: Sequence[str] | None = None,
                           sigma: float = 0.5, min_rotation_deg: float = 5.0,
                           held_out: Sequence[str] | None = None, robot: Robot | None = None,
                           q: ArrayLike | None = None, free: Sequence[str] = (),
                           model: str = "radtan") -> LensFit:
    """Held-out images kept aside (:func:`~kincal.identify.hand_eye_fit.split_images`),
    the rotation check, the closed-form start on the pixels undistorted with ``lens0``,
    :func:`fit_board_camera` on the training images, and the held-out images' raw-pixel
    reprojection RMS under the fitted ``X``, ``Z`` and intrinsics.

    ``free`` (with the ``robot`` and the joint values ``q`` (N, n) of the images;
    ``robot_poses`` = ``robot.fk(q)``): robot parameter names or patterns fitted too.
    Which of them the images identify is kincal's solver's answer on the pinhole fit
    with the pixels undistorted by ``lens0`` (eye-in-hand:
    :func:`~kincal.identify.hand_eye_fit.fit_hand_camera`; eye-to-hand:
    :func:`~kincal.identify.hand_eye_fixed.fixed_camera_robot_start`, which also
    holds those the images fix no better than their tolerances, ``held``); the joint
    fit then frees exactly those."""
    A = np.asarray(robot_poses, dtype=float)
    names = list(images)
    if not len(A) == len(points) == len(uv) == len(names):
        raise KincalError(f"{len(A)} poses, {len(points)} point sets, {len(uv)} pixel sets "
                          f"and {len(names)} image names")
    if len(set(names)) != len(names):
        raise KincalError("image names repeat")
    train, held = split_images(names, holdout)
    if held_out is not None:
        held = sorted(set(held_out))
        train = [n for n in sorted(names) if n not in held]
    if len(train) < 3:
        raise KincalError(f"{len(train)} training images: a hand-eye needs 3 at least "
                          "(better 10 or more)")
    idx = {n: k for k, n in enumerate(names)}
    it = [idx[n] for n in train]
    rot = check_rotations(A[it], min_rotation_deg, mount=mount)
    L0 = np.asarray(lens0, dtype=float)
    B = np.array([board_pose(points[k], undistort_model(uv[k], L0, model), L0[:4])[0]
                  for k in it])
    start = hand_eye(A[it], B, mount)
    held_robot: dict[str, str] = {}
    if free:
        if robot is None or q is None:
            raise KincalError("robot parameters are fitted from the robot and the joint "
                              "values of the images")
        Q = np.asarray(q, dtype=float)
        if mount == "fixed":
            fs = fixed_camera_robot_start(robot, Q[it], [points[k] for k in it],
                                          [undistort_model(uv[k], L0, model) for k in it],
                                          L0, free, sigma)
            rn, rv, X0, Z0, held_robot = fs.names, fs.values, fs.X, fs.Z, fs.held
        else:
            rn, rv, X0, Z0 = _robot_start(robot, Q[it], [points[k] for k in it],
                                          [undistort_model(uv[k], L0, model) for k in it],
                                          train, L0, free, sigma)

        def kin(th: Array) -> Array:
            return robot.with_params(dict(zip(rn, th.tolist(), strict=True))).fk(Q[it])

        fit = fit_board_camera(A[it], [points[k] for k in it], [uv[k] for k in it], train, L0,
                               X0, Z0, mount, fit_lens, sigma, kinematics=kin,
                               robot_names=rn, robot_values=rv, model=model)
        A = robot.with_params({n: v for n, (v, _) in fit.robot.items()}).fk(Q)
    else:
        fit = fit_board_camera(A[it], [points[k] for k in it], [uv[k] for k in it], train, L0,
                               start.X, start.Z, mount, fit_lens, sigma, model=model)
    fit.start, fit.rotation_deg, fit.held_out, fit.held = start, rot, held, held_robot
    if held:
        C = _chain(A[[idx[n] for n in held]], mount)
        e, e3 = {}, []
        for j, n in enumerate(held):
            P = points[idx[n]]
            e[n] = np.hypot(*_residuals([C[j]], [P], [uv[idx[n]]], fit.X, fit.Z,
                                        fit.lens, model).reshape(-1, 2).T)
            B = inverse(fit.X) @ C[j] @ fit.Z
            e3.append(e[n] * (P @ B[2, :3] + B[2, 3]) / (0.5 * (fit.lens[0] + fit.lens[1])))
        fit.held_per_image = {n: float(np.sqrt(np.mean(v**2))) for n, v in e.items()}
        fit.held_rms_px = float(np.sqrt(np.mean(np.concatenate(list(e.values())) ** 2)))
        fit.held_rms_3d = float(np.sqrt(np.mean(np.concatenate(e3) ** 2)))
    return fit


def _robot_start(robot: Robot, q: Array, points: Sequence[Array], uv: Sequence[Array],
                 images: Sequence[str], lens: Array, free: Sequence[str], sigma: float
                 ) -> tuple[list[str], Array, Array, Array]:
    """The robot parameters of ``free`` that the images identify, their values, ``X`` and
    ``Z`` from the pinhole fit on undistorted pixels (``fit_hand_camera``)."""
    block = HandCameraMeasurement("camera", np.repeat(q, [len(P) for P in points], axis=0),
                                  np.vstack(points), np.vstack(uv), sigma,
                                  tuple(float(v) for v in lens[:4]))
    labels = [n for n, P in zip(images, points, strict=True) for _ in range(len(P))]
    pin = fit_hand_camera(robot, block, labels, 0.0, free, 0.0)
    res = pin.result
    names = [n for n in res.estimated if not n.startswith(("tool.", "camera."))]
    return names, np.array([res.params[n] for n in names]), pin.X, pin.board


def lens_leave_one_out(robot_poses: Array, points: Sequence[Array], uv: Sequence[Array],
                       images: Sequence[str], lens0: ArrayLike, mount: str = "hand",
                       fit_lens: Sequence[str] | None = None, sigma: float = 0.5,
                       min_rotation_deg: float = 5.0, robot: Robot | None = None,
                       q: ArrayLike | None = None, free: Sequence[str] = (),
                       model: str = "radtan") -> LeaveOneOut:
    """:func:`calibrate_board_camera` once per image with that image held out: its
    reprojection RMS [px] and 3-D error [m], and the jackknife spread of the hand-eye
    (as :func:`~kincal.identify.hand_eye_fit.leave_one_out`)."""
    names = sorted(images)
    fits = [calibrate_board_camera(robot_poses, points, uv, images, lens0, mount, 0.0,
                                   fit_lens, sigma, min_rotation_deg, [n], robot, q, free,
                                   model)
            for n in names]
    X = np.array([f.X for f in fits])
    n = len(names)
    t = X[:, :3, 3]
    ang = np.linalg.norm(log_so3(X[:, :3, :3] @ average_pose(X)[:3, :3].T), axis=1)
    return LeaveOneOut(names, np.array([f.held_rms_px for f in fits]),
                       np.array([f.held_rms_3d for f in fits]),
                       float(np.sqrt((n - 1) / n * np.sum((t - t.mean(0)) ** 2))),
                       float(np.sqrt((n - 1) / n * np.sum(ang**2))))
