"""Robot parameters from a fixed camera watching a board on the flange (eye-to-hand).

The board is the robot's tool frame (``tool <- tool Z``, ``Z`` the board in the flange
frame); its corners ``s_j`` are known in the board frame.  The camera is fixed in the base
frame at ``{name}.camera.x, y, z, rz, ry, rx`` [m, rad] (the block's parameters)::

    w = R_e(q) s_j + p_e(q),      x = R_c^T (w - t_c),
    u = fx x_1 / x_3 + cx,        v = fy x_2 / x_3 + cy                      [px]

with ``dw/d(robot) = v - (w - p_e) x omega`` for the parameter twists ``[v; omega]`` of
the tool frame (:meth:`~kincal.robots.chain.Robot.fk_with_jacobians`) and ``dx/dw = R_c^T``.
Residuals ``(uv_pred - uv_obs) / sigma`` [1] (undistorted pixels).

:func:`fixed_camera_robot_start` is the eye-to-hand counterpart of the hand camera's
pinhole fit (:func:`~kincal.identify.hand_eye_fit.fit_hand_camera`): the closed-form
hand-eye (:func:`~kincal.identify.hand_eye.hand_eye`, ``mount="fixed"``) starts
:func:`~kincal.identify.solver.calibrate` over the camera pose, the board on the flange
and the robot parameters ``free``, with kincal's identifiability by name: of a dependent
group the camera and the board are kept (the first joint's offset turns the robot about
the base z axis as the camera's ``rz`` does, the last joint's offset turns the board as
``tool.rz`` does).  Then the tolerances of the laser-tracker fits
(:mod:`kincal.identify.tolerances`: 1 mm on lengths, 0.1 deg on angles, 0.5 deg on
joint offsets, or the robot file's) decide what is worth fitting: while some robot
parameter's standard error from the images (``sqrt(diag(H_kk^-1))``, ``H`` the images'
information over the parameters kept) is not below its tolerance, the one with the
largest ratio is held at nominal (the images would move it by more than the robot's
manufacturing can).  Every parameter of ``free`` not fitted is named with its reason:
not seen, moving the pixels as named others do, or fixed by the images only to
``std``, no better than its tolerance.

Measured (``python benchmarks/camera_fixed_free.py --trials 40``): Panda, fixed camera
0.6 m from a 5x7 ChArUco board, 16 images, 0.3 px, joint offsets of 0.4-0.7 deg and
1 mm link errors (``a[4]``, ``d[5]``), pinhole intrinsics fitted: the RMS of (estimate -
truth) / stated standard error is 0.84-1.19 per parameter, 1.04 over all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import IdentifiabilityError, KincalError
from kincal.identify.hand_eye import average_pose, hand_eye
from kincal.identify.names import match_names
from kincal.identify.prior import tolerance_prior
from kincal.identify.solver import calibrate
from kincal.measure.base import ParamSpec
from kincal.measure.camera_board import board_pose
from kincal.measure.instruments.camera import PixelRowsMeasurement, project
from kincal.measure.instruments.common import frame_spec, to_local
from kincal.robots.chain import Robot
from kincal.spatial import frame_from_matrix, inverse, matrix_from_frame

Array = NDArray[np.float64]

TOOL = tuple(f"tool.{f}" for f in ("x", "y", "z", "rz", "ry", "rx"))

__all__ = ["BoardOnFlangeMeasurement", "FixedStart", "fixed_camera_robot_start"]


class BoardOnFlangeMeasurement(PixelRowsMeasurement):
    """Pixels of board corners on the flange (the robot's tool frame) seen by a fixed
    camera (module docstring).

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        board_points: (N, 3) the corner of each row in the board (tool) frame [m].
        uv: (N, 2) undistorted pixels [px].
        sigma: standard deviation of each coordinate [px], scalar or (N,).
        intrinsics: ``(fx, fy, cx, cy)`` [px].
    """

    POINTS = "board_points"

    def parameters(self) -> ParamSpec:
        return frame_spec(f"{self.name}.camera")

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        T, _, Jp = robot.fk_with_jacobians(self.q, joints=False, params=jacobian)
        a = np.einsum("nij,nj->ni", T[:, :3, :3], self.s)
        w = a + T[:, :3, 3]
        x, dxdw, dxdc = to_local(np.asarray(extra, dtype=float).reshape(1, 6),
                                 np.zeros(len(w), dtype=np.intp), w, jacobian)
        uv, D = project(x, self.K, jacobian)
        r = ((uv - self.obs) / self.sigma[:, None]).reshape(-1)
        if not jacobian:
            return r, None, None
        assert Jp is not None and D is not None and dxdw is not None and dxdc is not None
        dw = Jp[:, :3] - np.cross(a[:, :, None], Jp[:, 3:], axis=1)
        scale = self.sigma[:, None, None]
        Jr = (D @ dxdw @ dw / scale).reshape(r.size, -1)
        Je = (D @ dxdc / scale).reshape(r.size, -1)
        return r, Jr, Je

    def residual_owner(self) -> NDArray[np.intp]:
        return np.repeat(np.arange(self.q.shape[0]), 2)

    def initial_guess(self, robot: Robot) -> Array:
        """The camera ``T(q_i) B_i^-1`` per pose (``B_i`` the board in the camera from its
        pixels, :func:`~kincal.measure.camera_board.board_pose`), averaged."""
        qs, idx = np.unique(self.q, axis=0, return_inverse=True)
        idx = idx.reshape(-1)
        C = []
        for k, T in enumerate(robot.fk(qs)):
            rows = idx == k
            if np.count_nonzero(rows) >= 4:
                B = board_pose(self.s[rows], self.obs[rows], self.intrinsics)[0]
                C.append(T @ inverse(B))
        if not C:
            raise KincalError(f"block {self.name!r}: no pose shows 4 board corners")
        return frame_from_matrix(average_pose(np.array(C)))

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0].reshape(-1, 2)
        return {"image_px": np.hypot(r[:, 0], r[:, 1]) * self.sigma}


@dataclass
class FixedStart:
    """The outcome of :func:`fixed_camera_robot_start` (m, rad).

    Attributes:
        names, values: the robot parameters to fit with the lens and their values.
        X: the camera in the base frame; Z: the board in the flange frame (4x4).
        held: ``{name: reason}`` of the parameters of ``free`` held at nominal.
        tolerance: ``{name: tolerance}`` of the fitted ones (the prior's sigma).
        data_std: ``{name: standard error from the images alone}`` of the fitted ones.
    """

    names: list[str]
    values: Array
    X: Array
    Z: Array
    held: dict[str, str] = field(default_factory=dict)
    tolerance: dict[str, float] = field(default_factory=dict)
    data_std: dict[str, float] = field(default_factory=dict)


def _text(name: str, units: dict[str, str], value: float) -> str:
    return (f"{value * 1e3:.3g} mm" if units.get(name) == "m"
            else f"{np.degrees(value):.3g} deg")


def _within_tolerance(names: Sequence[str], cov: Array, tol: dict[str, float],
                      robot_names: Sequence[str]) -> tuple[dict[str, float], dict[str, float]]:
    """Drop, one at a time, the robot parameter whose standard error from the images
    (``sqrt(diag((H_kk)^-1))``, ``H = Cov^-1`` the images' information, the dropped ones
    held) is the largest multiple of its tolerance, until every one left is below its
    tolerance.  Returns ``{dropped: its standard error when dropped}`` (in order) and
    ``{kept: standard error}``."""
    H = np.linalg.inv(cov)
    keep = list(range(len(names)))
    dropped: dict[str, float] = {}
    while True:
        std = np.sqrt(np.clip(np.diag(np.linalg.inv(H[np.ix_(keep, keep)])), 0.0, None))
        ratio = [std[j] / tol[names[k]] if names[k] in robot_names and names[k] in tol
                 else 0.0 for j, k in enumerate(keep)]
        worst = int(np.argmax(ratio))
        if ratio[worst] < 1.0:
            return dropped, {names[k]: float(std[j]) for j, k in enumerate(keep)}
        dropped[names[keep[worst]]] = float(std[worst])
        keep.pop(worst)


def fixed_camera_robot_start(robot: Robot, q: Array, points: Sequence[Array],
                             uv: Sequence[Array], lens: ArrayLike, free: Sequence[str],
                             sigma: float, name: str = "camera") -> FixedStart:
    """The robot parameters of ``free`` that the images of a fixed camera identify better
    than their tolerances, their values, the camera ``X`` (base frame) and the board
    ``Z`` (flange frame), from the pinhole fit on undistorted pixels (module docstring).

    ``q`` (N, n) the joints of the images, ``points[i]`` (n_i, 3) board corners [m],
    ``uv[i]`` (n_i, 2) undistorted pixels, ``lens`` starting with ``fx fy cx cy``,
    ``sigma`` the corner noise [px].  Raises :class:`IdentifiabilityError` (one line)
    when the camera or the board is not identified."""
    Q = np.asarray(q, dtype=float)
    K = np.asarray(lens, dtype=float).reshape(-1)[:4]
    B = np.array([board_pose(P, u, K)[0] for P, u in zip(points, uv, strict=True)])
    start = hand_eye(robot.fk(Q), B, "fixed")
    tool0 = matrix_from_frame(robot.frame_parameters("tool"))
    robot0 = robot.with_params(dict(zip(TOOL, frame_from_matrix(tool0 @ start.Z).tolist(),
                                        strict=True)))
    block = BoardOnFlangeMeasurement(name, np.repeat(Q, [len(P) for P in points], axis=0),
                                     np.vstack(points), np.vstack(uv), sigma, tuple(K))
    cam = list(block.parameters().names)
    wanted = [robot.param_names[i] for i in match_names(robot.param_names, list(free))
              if robot.param_names[i] not in TOOL]         # the tool frame is the board
    res = calibrate(robot0, [block], free=[*TOOL, f"{name}.camera.*", *wanted],
                    initial=dict(zip(cam, frame_from_matrix(start.X).tolist(), strict=True)),
                    prefer=[*TOOL, f"{name}.camera.*"])
    missing = [n for n in (*TOOL, *cam) if n not in res.estimated]
    if missing:
        raise IdentifiabilityError(f"the images cannot identify the camera and the board "
                                   f"({', '.join(missing)} held): add poses that turn the "
                                   "board about other axes")
    units = dict(zip(res.problem.names, res.problem.units, strict=True))
    tol = tolerance_prior(robot0, res.problem, "tolerances")
    rep = res.identifiability
    dropped, std = _within_tolerance(list(res.estimated), res.covariance, tol, wanted)
    out = FixedStart([], np.zeros(0), matrix_from_frame([res.params[n] for n in cam]),
                     inverse(tool0) @ matrix_from_frame([res.params[n] for n in TOOL]))
    for n in wanted:
        if n in std:
            out.names.append(n)
            out.tolerance[n], out.data_std[n] = tol.get(n, np.inf), std[n]
        elif n in dropped:
            out.held[n] = (f"the images fix it only to {_text(n, units, dropped[n])} (1 "
                           f"sigma), no better than its tolerance {_text(n, units, tol[n])}")
        elif n in rep.unobservable:
            out.held[n] = "the images do not see it"
        else:
            out.held[n] = ("it moves the pixels as " + ", ".join(rep.dependent.get(n, [])[:3])
                           + " do (kept instead)")
    out.values = np.array([res.params[n] for n in out.names])
    return out
