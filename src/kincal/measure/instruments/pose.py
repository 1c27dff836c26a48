"""The ``pose`` instrument (6-DOF tracker probe, CMM probed frame): model, file, simulator.

The model observes a target frame ``T_t`` on the tool (``{name}.target.x ... .rx``) from
an instrument frame ``T_I`` (``{name}.x .y .z .rz .ry .rx``, ``T_I = Trans(x, y, z)
Rz(rz) Ry(ry) Rx(rx)`` [m, rad]) as ``T_obs = T_I^-1 T_e(q) T_t``; residual per pose

    r = [(p_pred - p_obs) / sigma_p ; log(R_pred R_obs^T) / sigma_o]

(position [m] then rotation vector [rad], both in the instrument frame).  For the
orientation residual ``e = log(R_pred R_obs^T)``, a left perturbation ``R_pred ->
exp(delta) R_pred`` changes ``e`` by ``J_l^-1(e) delta`` (the inverse left Jacobian of
SO(3)).  The closed-form start solves ``R_e R_t = R_I R_obs`` (AX = YB) by the null
space of its Kronecker form, then the translations linearly.

File columns (instrument ``pose``): joints, ``x y z`` [length], ``rx ry rz`` [angle]
(roll-pitch-yaw, ``R = Rz(rz) Ry(ry) Rx(rx)``), optional ``sigma`` [length] and
``sigma_rot`` [angle].

Simulation: :func:`simulate_poses` measures the configurations you give;
:func:`simulate_pose_experiment` (the plug-in behind ``kincal simulate -i pose``) draws
configurations and set-up and adds position noise and a random rotation ``exp(w)``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import (
    CHUNK_ROWS,
    MeasurementModel,
    ParamSpec,
    Provenance,
    Triangle,
    configuration_slices,
    frame_rotation_axes,
)
from kincal.measure.files import Field, MeasurementTable, read_table, write_table
from kincal.measure.instruments.common import (
    check_configurations,
    inverse_left_jacobian_so3,
    project_so3,
    rotate_twists,
    sigma_array,
)
from kincal.measure.instruments.csvio import one_block
from kincal.measure.instruments.placement import truth_values
from kincal.measure.instruments.position import (
    DEFAULT_SIGMA,
    TRACKER_OPTIONS,
    UNNAMED,
    check_positive,
    file_units,
    instrument_matrix,
    random_tracker_frame,
    scalar_sigma,
    tag_sigma,
)
from kincal.measure.orientation import (
    AXIS_SIGMAS,
    pose_rotations,
    pose_sigmas,
    quaternion_units,
)
from kincal.measure.registry import Instrument, register
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot
from kincal.robots.workspace import ChainWorkspace
from kincal.spatial import (
    exp_so3,
    frame_from_matrix,
    homogeneous,
    log_so3,
    matrix_from_frame,
    matrix_to_rpy,
)

Array = NDArray[np.float64]

__all__ = ["PoseMeasurement", "simulate_poses", "simulate_pose_experiment", "read_pose",
           "write_pose"]


class PoseMeasurement(MeasurementModel):
    """Full poses of a target frame on the tool measured in an instrument frame.

    Args:
        q: (N, n) joint readings [rad / m].
        poses: (N, 4, 4) measured target frames in the instrument frame [m].
        sigma_position: standard deviation of each position coordinate [m], scalar or (N,).
        sigma_orientation: standard deviation of each rotation-vector component [rad].
        name: the block's name, prefix of its parameters.

    Parameters: ``{name}.x .y .z .rz .ry .rx`` (instrument frame, role ``instrument``)
    and ``{name}.target.x .y .z .rz .ry .rx`` (target frame in the tool frame, role
    ``target``).  Residuals per pose: ``[dp / sigma_p; log(R_pred R_obs^T) / sigma_o]``.
    """

    def __init__(self, q: ArrayLike, poses: ArrayLike, sigma_position: ArrayLike = 1e-5,
                 sigma_orientation: ArrayLike = 1e-5, name: str = "tracker",
                 orientation_axes: ArrayLike | None = None) -> None:
        self.name = str(name)
        self.q = check_configurations(q, self.name)
        P = np.asarray(poses, dtype=float)
        if P.ndim != 3 or P.shape[1:] != (4, 4) or P.shape[0] != self.q.shape[0]:
            raise KincalError(f"measurements {self.name!r}: poses must be (N, 4, 4) with "
                              f"N = {self.q.shape[0]}, got {P.shape}")
        if not np.all(np.isfinite(P)):
            row = int(np.argwhere(~np.isfinite(P))[0, 0])
            raise KincalError(f"measurements {self.name!r}: pose in row {row} is not finite")
        self.poses = P
        N = self.q.shape[0]
        self.sigma_position = _row_or_axis_sigma(sigma_position, N,
                                                 f"{self.name}: sigma_position")
        self.sigma_orientation = _row_or_axis_sigma(sigma_orientation, N,
                                                    f"{self.name}: sigma_orientation")
        self.orientation_axes = _orientation_axes(orientation_axes, self.sigma_orientation,
                                                  self.name)
        self._weights: tuple[Array, Array | None, Array | None] | None = None

    def _whitening(self) -> tuple[Array, Array | None, Array | None]:
        """``(wp, wo, Wo)``: position weights ``1 / sigma`` per row and axis (N, 3);
        rotation weights ``1 / sigma_o`` per row (N,) with one orientation sigma per row,
        else None and ``Wo`` (N, 3, 3) = ``L^-1`` with ``L L^T = E diag(s^2) E^T`` (the
        rotation error's covariance; ``E`` = ``orientation_axes``, identity without),
        so that ``Wo^T Wo`` is its inverse.  Computed once."""
        if self._weights is None:
            sp, so = self.sigma_position, self.sigma_orientation
            wp = 1.0 / (sp if sp.ndim == 2 else sp[:, None] * np.ones((1, 3)))
            if so.ndim == 1:
                self._weights = (wp, 1.0 / so, None)
            else:
                E = self.orientation_axes if self.orientation_axes is not None \
                    else np.broadcast_to(np.eye(3), (self.N, 3, 3))
                C = (E * so[:, None, :] ** 2) @ np.swapaxes(E, 1, 2)
                L = np.linalg.cholesky(C)
                self._weights = (wp, None, np.linalg.inv(L))
        return self._weights

    @property
    def N(self) -> int:
        return int(self.q.shape[0])

    def measurement_sigma(self) -> Array:
        """Stated standard deviation of each position [m]: (N,), or (N, 3) one per
        instrument axis (orientations: ``sigma_orientation`` [rad])."""
        return self.sigma_position

    def parameters(self) -> ParamSpec:
        return ParamSpec.frame(self.name) + ParamSpec.frame(f"{self.name}.target", role="target")

    def residual_owner(self) -> NDArray[np.intp]:
        return np.repeat(np.arange(self.N, dtype=np.intp), 6)

    def subset(self, rows: ArrayLike) -> PoseMeasurement:
        """A block with the same name holding only ``rows``."""
        rows = np.asarray(rows)
        axes = self.orientation_axes[rows] if self.orientation_axes is not None else None
        return PoseMeasurement(self.q[rows], self.poses[rows], self.sigma_position[rows],
                               self.sigma_orientation[rows], self.name, axes)

    def predict(self, robot: Robot, extra: ArrayLike) -> Array:
        """Predicted target poses in the instrument frame (N, 4, 4)."""
        extra = np.asarray(extra, dtype=float)
        TI = matrix_from_frame(extra[:6])
        Tt = matrix_from_frame(extra[6:12])
        return np.linalg.inv(TI) @ robot.fk(self.q) @ Tt

    def num_residuals(self) -> int:
        return 6 * self.N

    @staticmethod
    def _frames(extra: Array) -> tuple[Array, Array, Array, Array]:
        """Constants of one evaluation: ``T_I``, ``T_t`` and their rotation axes ``E_I``,
        ``E_t`` (:func:`frame_rotation_axes`)."""
        return (matrix_from_frame(extra[:6]), matrix_from_frame(extra[6:12]),
                frame_rotation_axes(extra[:6]), frame_rotation_axes(extra[6:12]))

    def _raw(self, T: Array, frames: tuple[Array, Array, Array, Array], cs: slice
             ) -> tuple[Array, Array, Array, Array]:
        """For frames ``T`` of configurations ``cs``: position errors ``y - p_obs``
        (n, 3) [m], rotation errors ``e = log(R_pred R_obs^T)`` (n, 3) [rad], the target
        offset ``a = R_e t_t`` and the prediction ``y = R_I^T (p_e + a - t_I)`` (n, 3)."""
        TI, Tt = frames[0], frames[1]
        RI, tI = TI[:3, :3], TI[:3, 3]
        Re = T[:, :3, :3]
        a = Re @ Tt[:3, 3]                                         # target origin offset
        y = (T[:, :3, 3] + a - tI) @ RI                            # R_I^T d
        Rp = RI.T @ Re @ Tt[:3, :3]                                # R_pred (n, 3, 3)
        e = log_so3(Rp @ np.swapaxes(self.poses[cs, :3, :3], 1, 2))
        return y - self.poses[cs, :3, 3], e, a, y

    def evaluate(self, robot: Robot, extra: Array, jacobian: bool = True
                 ) -> tuple[Array, Array | None, Array | None]:
        extra = np.asarray(extra, dtype=float)
        if not jacobian:
            dy, e, _, _ = self._raw(robot.fk(self.q), self._frames(extra), slice(None))
            wp, wo, Wo = self._whitening()
            if wo is not None:
                eo = e * wo[:, None]
            else:
                assert Wo is not None                             # per-angle sigmas
                eo = (Wo @ e[:, :, None])[:, :, 0]
            return np.concatenate([dy * wp, eo], 1).reshape(-1), None, None
        M, P = self.num_residuals(), robot.num_params
        r, Jr, Je = np.empty(M), np.empty((M, P)), np.empty((M, 12))
        ws, frames = ChainWorkspace(), self._frames(extra)
        for cs in configuration_slices(self.N, 6, CHUNK_ROWS):
            rs = slice(6 * cs.start, 6 * cs.stop)
            self._fill(robot, frames, cs, r[rs], Jr[rs], Je[rs], ws)
        return r, Jr, Je

    def evaluate_chunks(self, robot: Robot, extra: Array, rows: int = CHUNK_ROWS
                        ) -> Iterator[tuple[slice, Array, Array, Array]]:
        extra = np.asarray(extra, dtype=float)
        P = robot.num_params
        ws, frames = ChainWorkspace(), self._frames(extra)
        for cs in configuration_slices(self.N, 6, rows):
            n = 6 * (cs.stop - cs.start)
            r, Jr, Je = np.empty(n), np.empty((n, P)), np.empty((n, 12))
            self._fill(robot, frames, cs, r, Jr, Je, ws)
            yield slice(6 * cs.start, 6 * cs.stop), r, Jr, Je

    def _fill(self, robot: Robot, frames: tuple[Array, Array, Array, Array], cs: slice,
              r: Array, Jr: Array, Je: Array, ws: ChainWorkspace) -> None:
        """Residuals and Jacobians of configurations ``cs`` into ``r`` (6n,), ``Jr``
        (6n, P), ``Je`` (6n, 12) (rows: position x y z, then rotation, per pose).

        With ``Jv' = R_I^T Jv``, ``Jw' = R_I^T Jw``, ``a' = R_I^T R_e t_t``,
        ``y = R_I^T (p_e + a - t_I)``, ``L = J_l^-1(e)`` (:func:`inverse_left_jacobian_so3`),
        ``E'_c = R_I^T E_c`` (instrument rotation axes) and ``F_c`` the target's:

        * robot: position ``Jv'_i + Jw'_j a'_k - Jw'_k a'_j`` ((i, j, k) cyclic),
          rotation ``L Jw'`` (``R_pred`` turns by ``R_I^T dphi_e``);
        * instrument: position ``[-R_I^T, y x E'_c]``, rotation ``[0, -L E'_c]``;
        * target: position ``[R_I^T R_e, 0]``, rotation ``[0, L R_I^T R_e F_c]``;

        position rows divided by ``sigma_position`` (per row or per axis), rotation rows
        by ``sigma_orientation``, or multiplied by the whitening ``Wo`` of per-angle ones
        (:meth:`_whitening`).
        """
        T, _, Jp = robot.fk_with_jacobians(self.q[cs], joints=False, params=True, workspace=ws)
        n, P = T.shape[0], robot.num_params
        G = frames[0][:3, :3].T                                   # R_I^T
        dy, e, a, y = self._raw(T, frames, cs)
        wp_all, wo_all, Wo_all = self._whitening()
        wp = wp_all[cs]
        wo = wo_all[cs] if wo_all is not None else np.ones(n)
        rr = r.reshape(n, 6)
        np.multiply(dy, wp, out=rr[:, :3])
        np.multiply(e, wo[:, None], out=rr[:, 3:])
        L = inverse_left_jacobian_so3(e)                           # (n, 3, 3)
        assert Jp is not None                                      # params=True
        V, W = rotate_twists(G, Jp, ws)                           # R_I^T Jv, R_I^T Jw
        ar = np.ascontiguousarray((a @ G.T).T)                    # a' (3, n)
        Lc = np.ascontiguousarray(L.transpose(1, 2, 0))           # (3, 3, n)
        out = Jr.reshape(n, 6, P)
        buf, tmp = ws.array("fill.buf", (P, n)), ws.array("fill.tmp", (P, n))
        for i in range(3):
            j, l = (i + 1) % 3, (i + 2) % 3
            np.multiply(W[j], ar[l], out=buf)
            np.multiply(W[l], ar[j], out=tmp)
            buf -= tmp
            buf += V[i]
            buf *= wp[:, i]
            out[:, i, :] = buf.T
            np.multiply(W[0], Lc[i, 0], out=buf)
            for c in (1, 2):
                np.multiply(W[c], Lc[i, c], out=tmp)
                buf += tmp
            buf *= wo
            out[:, 3 + i, :] = buf.T
        ex = Je.reshape(n, 6, 12)
        ex[...] = 0.0
        ex[:, :3, 0:3] = -G
        Ep = G @ frames[2]                                        # E'_c as columns
        for i in range(3):
            j, l = (i + 1) % 3, (i + 2) % 3
            ex[:, i, 3:6] = y[:, j, None] * Ep[l] - y[:, l, None] * Ep[j]
        ex[:, 3:, 3:6] = L @ -Ep
        RiRe = G @ T[:, :3, :3]
        ex[:, :3, 6:9] = RiRe
        ex[:, 3:, 9:12] = L @ (RiRe @ frames[3])
        ex[:, :3] *= wp[:, :, None]
        ex[:, 3:] *= wo[:, None, None]
        if Wo_all is not None:                                    # per-angle sigmas
            Wo = Wo_all[cs]
            rr[:, 3:] = (Wo @ rr[:, 3:, None])[:, :, 0]
            out[:, 3:] = Wo @ out[:, 3:]
            ex[:, 3:] = Wo @ ex[:, 3:]

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        frames = self._frames(np.asarray(extra, dtype=float))
        dy, e, _, _ = self._raw(robot.fk(self.q), frames, slice(None))
        return {"position_m": np.linalg.norm(dy, axis=1),
                "orientation_rad": np.linalg.norm(e, axis=1)}

    def initial_guess(self, robot: Robot) -> Array:
        """Instrument and target frames in closed form (AX = YB).

        Rotations: ``R_e,i R_t - R_I R_obs,i = 0`` is linear in ``(vec R_t, vec R_I)``:
        ``[(I kron R_e,i), -(R_obs,i^T kron I)] [vec R_t; vec R_I] = 0``; the right
        singular vector of the smallest singular value, scaled to ``det R_t = 1`` and
        projected onto SO(3).  Translations: ``R_e,i t_t - t_I = R_I p_obs,i - p_e,i``
        by linear least squares.  Both systems are reduced to their QR triangles in one
        pass over the configurations, in pieces (the translations' right-hand side is
        linear in ``R_I``: its ten columns ``-p_e``, ``p_obs,b e_a`` are carried along).
        """
        eye = np.eye(3)
        rot, tra = Triangle(18), Triangle(6 + 10)
        for cs in configuration_slices(self.N, 6, CHUNK_ROWS):
            T = robot.fk(self.q[cs])
            Re, pe = T[:, :3, :3], T[:, :3, 3]
            Ro, po = self.poses[cs, :3, :3], self.poses[cs, :3, 3]
            rot.add(np.concatenate([np.kron(eye[None], Re),
                                    -np.kron(np.swapaxes(Ro, 1, 2), eye[None])],
                                   axis=2).reshape(-1, 18))
            # R_e t_t - t_I = R_I p_obs - p_e: right-hand sides -p_e and p_obs,b e_a
            B = np.zeros((len(Re), 3, 16))
            B[:, :, :3] = Re
            B[:, :, 3:6] = -eye
            B[:, :, 6] = -pe
            for a in range(3):
                B[:, a, 7 + 3 * a: 10 + 3 * a] = po
            tra.add(B.reshape(-1, 16))
        _, _, Vt = np.linalg.svd(rot.R)
        v = Vt[-1]
        X = v[:9].reshape(3, 3, order="F")
        Y = v[9:].reshape(3, 3, order="F")
        det = np.linalg.det(X)
        c = np.sign(det) * abs(det) ** (-1.0 / 3.0) if abs(det) > 1e-300 else 1.0
        Rt, RI = project_so3(c * X), project_so3(c * Y)
        Z = tra.solve(6)                                            # (6, 10)
        sol = Z[:, 0] + Z[:, 1:] @ RI.reshape(9)
        TI, Tt = np.eye(4), np.eye(4)
        TI[:3, :3], TI[:3, 3] = RI, sol[3:]
        Tt[:3, :3], Tt[:3, 3] = Rt, sol[:3]
        return np.concatenate([frame_from_matrix(TI), frame_from_matrix(Tt)])


def _row_or_axis_sigma(sigma: ArrayLike, N: int, what: str) -> Array:
    """A standard deviation per row (scalar or (N,) -> (N,)) or per row and axis
    ((N, 3) kept), positive and finite."""
    s = np.asarray(sigma, dtype=float)
    if s.ndim == 2 and s.shape == (N, 3):
        return sigma_array(s, (N, 3), what)
    return sigma_array(s, (N,), what)


def _orientation_axes(axes: ArrayLike | None, sigma: Array, name: str) -> Array | None:
    """The (N, 3, 3) rotation axes of per-angle orientation sigmas, checked."""
    if axes is None:
        return None
    E = np.asarray(axes, dtype=float)
    if sigma.ndim != 2 or E.shape != (sigma.shape[0], 3, 3) or not np.all(np.isfinite(E)):
        raise KincalError(f"measurements {name!r}: orientation_axes must be finite (N, 3, 3) "
                          "with one sigma_orientation per angle (N, 3)")
    if np.any(np.abs(np.linalg.det(E)) < 1e-9):
        raise KincalError(f"measurements {name!r}: orientation_axes are singular (an Euler "
                          "angle set at gimbal lock): its per-angle sigmas do not bound the "
                          "rotation")
    return E


# --------------------------------------------------------------------------- file columns
POSE_FIELDS = (
    Field(r"[xyz]", "length", "x, y, z"),
    Field(r"r[xyz]", "angle", "rx, ry, rz (roll-pitch-yaw)"),
    Field(r"sigma", "length", "sigma (position standard deviation)"),
    Field(r"sigma_rot", "angle", "sigma_rot (orientation standard deviation)"),
    Field(r"q[wxyz]", "dimensionless", "qw, qx, qy, qz (unit quaternion)"),
    Field(r"sigma_[xyz]", "length", "sigma_x, sigma_y, sigma_z (per axis)"),
    Field(r"sigma_r[xyz]", "angle", "sigma_rx, sigma_ry, sigma_rz (per axis)"),
)


def pose_matrices(t: MeasurementTable) -> Array:
    """(N, 4, 4) poses from the ``x y z`` columns and the orientation columns of a table
    (their convention: the ``orientation`` tag, :mod:`kincal.measure.orientation`)."""
    for c in ("x", "y", "z"):
        if c not in t.values:
            raise t.error(f"missing column {c!r} (with its unit, e.g. {c}_mm)")
    R, _ = pose_rotations(t)
    p = np.stack([t.values[c] for c in "xyz"], axis=1)
    return homogeneous(R, p)


def write_pose(blocks: Sequence[Any], path: str | Path, units: Mapping[str, str] | None = None,
               robot: Any = None) -> None:
    """Write one :class:`PoseMeasurement` as a ``pose`` CSV (rpy angles), atomically."""
    b = one_block(blocks, "pose")
    length, angle = file_units(units)
    P = np.asarray(b.poses, dtype=float)
    rpy = matrix_to_rpy(P[:, :3, :3])
    obs = [(c, P[:, i, 3], "length") for i, c in enumerate("xyz")]
    obs += [(c, rpy[:, i], "angle") for i, c in enumerate(("rx", "ry", "rz"))]
    sp, so = np.asarray(b.sigma_position), np.asarray(b.sigma_orientation)
    if sp.ndim == 2:                                     # per instrument axis
        obs += [(f"sigma_{c}", sp[:, i], "length") for i, c in enumerate("xyz")]
    else:
        obs += [("sigma", np.broadcast_to(sp, (len(P),)), "length")]
    # per-angle orientation sigmas of another convention: their RMS per row (the
    # file's rpy angles are not the angles they were stated for)
    so = np.sqrt(np.mean(so**2, axis=1)) if so.ndim == 2 else so
    obs += [("sigma_rot", np.broadcast_to(so, (len(P),)), "angle")]
    write_table(path, b.q, obs, robot, {"instrument": "pose", "name": b.name},
                angle_unit=angle, length_unit=length,
                comments=["pose of the target frame in the instrument frame; rx, ry, rz "
                          "roll-pitch-yaw: R = Rz(rz) Ry(ry) Rx(rx)"])


def read_pose(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
              ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``pose`` CSV into one :class:`PoseMeasurement` (SI units)."""
    t = read_table(path, robot, POSE_FIELDS, {**quaternion_units(path), **dict(units or {})},
                   ignore)
    P = pose_matrices(t)
    for b in ("sigma", "sigma_rot", *AXIS_SIGMAS[0], *AXIS_SIGMAS[1]):
        check_positive(t, b)
    sig = pose_sigmas(t, pose_rotations(t)[1])
    sp = sig.position if sig.position is not None and sig.position.ndim == 2 \
        else scalar_sigma(sig.position, tag_sigma(t, "sigma"))
    so = sig.orientation if sig.orientation is not None and sig.orientation.ndim == 2 \
        else scalar_sigma(sig.orientation, tag_sigma(t, "sigma_rot"))
    block = PoseMeasurement(t.q, P, sigma_position=sp, sigma_orientation=so,
                            name=name or t.tags.get("name") or UNNAMED,
                            orientation_axes=sig.orientation_axes)
    block.provenance = Provenance(str(path), t)
    return [block]


# --------------------------------------------------------------------------- simulation
def simulate_poses(true_robot: Robot, q: ArrayLike, rng: np.random.Generator,
                   noise_position_std: float, noise_orientation_std: float,
                   instrument: ArrayLike | None = None, target: ArrayLike | None = None,
                   name: str = "tracker", sigma_position: float | None = None,
                   sigma_orientation: float | None = None) -> PoseMeasurement:
    """Target frames on the true robot's tool measured by a virtual 6-DOF tracker.

    ``T_obs = T_I^-1 T(q) T_t`` then perturbed: position + N(0, noise_position_std^2)
    per coordinate, rotation ``exp([n]x) R`` with ``n ~ N(0, noise_orientation_std^2)``
    per component [rad].

    Args:
        instrument: the instrument frame ``(x, y, z, rz, ry, rx)`` [m, rad]
            (:data:`kincal.spatial.FRAME_FIELDS`, the order of the estimated block
            parameters); default identity.
        target: the measured frame on the tool, ``(x, y, z, rz, ry, rx)`` [m, rad];
            default identity.
        sigma_position: stated standard deviation of the positions [m]; default the
            noise (or 1e-5 when the noise is 0).
        sigma_orientation: stated standard deviation of the orientations [rad]; default
            the noise (or 1e-5 when the noise is 0).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    TI = instrument_matrix(instrument)
    Tt = instrument_matrix(target)
    T = np.linalg.inv(TI) @ true_robot.fk(q) @ Tt
    N = len(q)
    T[:, :3, 3] += noise_position_std * rng.standard_normal((N, 3))
    T[:, :3, :3] = exp_so3(noise_orientation_std * rng.standard_normal((N, 3))) @ T[:, :3, :3]
    sp = sigma_position if sigma_position is not None else (noise_position_std or 1e-5)
    so = sigma_orientation if sigma_orientation is not None else (noise_orientation_std or 1e-5)
    return PoseMeasurement(q, T, sp, so, name)


def simulate_pose_experiment(true_robot: Robot, rng: np.random.Generator, n_poses: int,
                             noise: float, orientation_noise_deg: float = 0.005,
                             name: str = "tracker", margin: float = 0.05,
                             truth: Mapping[str, float] | None = None
                             ) -> tuple[list[MeasurementModel], dict[str, float]]:
    """The ``pose`` plug-in: draw the poses and the set-up, then measure a tool frame.

    Configurations, instrument frame and target are drawn like
    :func:`~kincal.measure.instruments.position.simulate_position_experiment`'s;
    :func:`simulate_poses` measures configurations you give.

    ``T_obs = T_I^-1 T_e(q) T_t`` perturbed by ``N(0, noise^2)`` per position coordinate
    [m] and a rotation ``exp(w)``, ``w ~ N(0, s^2)`` per component, ``s`` =
    ``orientation_noise_deg`` in radians.
    """
    q = random_configurations(true_robot, n_poses, rng, margin)
    so = np.deg2rad(float(orientation_noise_deg))
    probe = PoseMeasurement(q[:1], np.eye(4)[None], name=name)
    names = probe.parameters().names
    if truth is not None:
        values = truth_values(truth, names)
    else:
        target = np.concatenate([rng.uniform(-0.05, 0.05, 3) + [0, 0, 0.05],
                                 rng.uniform(-0.3, 0.3, 3)])
        values = np.concatenate([random_tracker_frame(rng), target])
    TI, Tt = matrix_from_frame(values[:6]), matrix_from_frame(values[6:])
    P = np.linalg.inv(TI) @ true_robot.fk(q) @ Tt
    if noise > 0:
        P[:, :3, 3] += rng.normal(0.0, noise, (len(q), 3))
    if so > 0:
        P[:, :3, :3] = exp_so3(rng.normal(0.0, so, (len(q), 3))) @ P[:, :3, :3]
    block = PoseMeasurement(q, P, sigma_position=noise if noise > 0 else DEFAULT_SIGMA,
                            sigma_orientation=so if so > 0 else DEFAULT_SIGMA, name=name)
    return [block], dict(zip(names, values.tolist(), strict=True))


POSE = register(Instrument(
    name="pose",
    description="full pose of a frame on the tool in an instrument frame (6-DOF tracker)",
    simulate=simulate_pose_experiment, write=write_pose, read=read_pose,
    options={"orientation_noise_deg": (0.005, "orientation noise (deg, per axis)"),
             **TRACKER_OPTIONS},
    noise_unit="m"))
