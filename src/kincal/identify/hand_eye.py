"""Closed-form hand-eye start that does not depend on the order of the samples.

Every sample ``i`` gives a robot pose ``A_i`` (4x4, base -> flange) and the board's pose
seen by the camera ``B_i`` (4x4, camera -> board).  Eye-in-hand (camera on the flange,
board fixed): ``A_i X B_i = Z`` for every ``i``, with ``X`` the camera in the flange frame
and ``Z`` the board in the base frame.  Eye-to-hand (camera fixed, board on the flange):
``A_i^-1 X B_i = Z`` with ``X`` the camera in the base frame and ``Z`` the board in the
flange frame -- the same equations with ``A_i`` inverted (:func:`hand_eye`,
``mount="fixed"``).

Every *ordered pair* ``i != j`` gives a relative motion ``A = A_j^-1 A_i``, ``B = B_j
B_i^-1`` with ``A X = X B``.  Over all ``N (N - 1)`` ordered pairs:

* rotation: with unit quaternions (scalar first, ``w >= 0``), ``q_A q_X = q_X q_B`` is
  linear in ``q_X``: ``(L(q_A) - R(q_B)) q_X = 0``, ``L``, ``R`` the left / right
  multiplication matrices; ``q_X`` is the eigenvector of the smallest eigenvalue of
  ``S = sum (L - R)^T (L - R)`` (4x4);
* translation: ``(R_A - I) t_X = R_X t_B - t_A``, solved by least squares over all pairs
  (3x3 normal equations).

Both sums run over the *set* of ordered pairs, so shuffling the samples changes nothing
but the order of floating-point additions (the answer agrees to ~1e-15).  A pair and its
reverse (the inverse motion) give the same rotation equation up to unit quaternion
factors (the same sum); their translation equations, ``(R_A - I) t_X = R_X t_B - t_A``
and, multiplied by ``-R_A``, ``(R_A - I) t_X = R_A R_X R_B^T t_B - t_A``, agree only when
the rotations fit exactly: with noise, one orientation per pair (``i < j`` in the
samples' order) would make ``t_X`` depend on the order (0.08 mm median with 0.5 px and
0.2 mm of robot noise, ``benchmarks/hand_eye.py``), so both enter.  ``Z`` is the mean of
``A_i X B_i`` (rotations averaged by projecting their sum on SO(3)).

:func:`rotation_spread` measures how much the flange turned about each principal axis:
the hand-eye rotation and the translation along an axis need rotations about two axes
at least; :func:`check_rotations` refuses in one line naming the axes that are missing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import IdentifiabilityError, KincalError
from kincal.spatial import inverse, log_so3

Array = NDArray[np.float64]

__all__ = ["HandEye", "hand_eye", "robot_world", "quaternion", "rotation_spread",
           "check_rotations", "average_pose"]


def quaternion(R: ArrayLike) -> Array:
    """Unit quaternion ``(w, x, y, z)`` of rotation(s) ``R`` (..., 3, 3), ``w >= 0``:
    ``(cos(phi/2), sin(phi/2) a)`` from the rotation vector ``phi a = log(R)``."""
    w = log_so3(np.asarray(R, dtype=float))
    phi = np.linalg.norm(w, axis=-1, keepdims=True)
    axis = np.where(phi > 1e-300, w / np.where(phi > 1e-300, phi, 1.0), 0.0)
    return np.concatenate([np.cos(phi / 2.0), np.sin(phi / 2.0) * axis], axis=-1)


def _left(q: Array) -> Array:
    """``L(p)`` with ``p q = L(p) q`` (quaternions (..., 4), scalar first)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, -z, y], -1),
                     np.stack([y, z, w, -x], -1), np.stack([z, -y, x, w], -1)], -2)


def _right(q: Array) -> Array:
    """``R(q)`` with ``p q = R(q) p``."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([w, -x, -y, -z], -1), np.stack([x, w, z, -y], -1),
                     np.stack([y, -z, w, x], -1), np.stack([z, y, -x, w], -1)], -2)


def _pairs(n: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    i, j = np.triu_indices(n, 1)
    return i.astype(np.intp), j.astype(np.intp)


def _check(T: ArrayLike, what: str) -> Array:
    a = np.asarray(T, dtype=float)
    if a.ndim != 3 or a.shape[1:] != (4, 4) or not np.all(np.isfinite(a)):
        raise KincalError(f"{what}: expected finite (N, 4, 4) transforms")
    return a


def average_pose(T: ArrayLike) -> Array:
    """Mean of transforms (N, 4, 4): translations averaged, the rotations' sum projected
    on SO(3) by SVD (the chordal mean)."""
    T = _check(T, "poses")
    U, _, Vt = np.linalg.svd(T[:, :3, :3].sum(0))
    out = np.eye(4)
    out[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    out[:3, 3] = T[:, :3, 3].mean(0)
    return out


@dataclass
class HandEye:
    """A closed-form hand-eye solution.

    Attributes:
        X: eye-in-hand: the camera in the flange frame; eye-to-hand: the camera in the
            base frame (4x4, m).
        Z: eye-in-hand: the board in the base frame; eye-to-hand: the board in the
            flange frame (4x4, m).
        rotation_rms_deg: RMS of the rotation residual angle of ``A X = X B`` over the
            pairs [deg].
        translation_rms: RMS of ``|(R_A - I) t_X - R_X t_B + t_A|`` over the pairs [m].
        consistency: per sample, the distance of ``A_i X B_i`` from ``Z`` [m].
    """

    X: Array
    Z: Array
    rotation_rms_deg: float
    translation_rms: float
    consistency: Array


def hand_eye(robot_poses: ArrayLike, board_poses: ArrayLike, mount: str = "hand") -> HandEye:
    """Closed-form hand-eye (module docstring).

    Args:
        robot_poses: (N, 4, 4) flange poses in the base frame [m].
        board_poses: (N, 4, 4) board poses in the camera frame [m].
        mount: ``"hand"`` (camera on the flange) or ``"fixed"`` (camera fixed, board on
            the flange).
    """
    A = _check(robot_poses, "robot poses")
    B = _check(board_poses, "board poses")
    if len(A) != len(B):
        raise KincalError(f"{len(A)} robot poses but {len(B)} board poses")
    if len(A) < 3:
        raise IdentifiabilityError(f"{len(A)} images: a hand-eye needs at least 3 poses "
                                   "(rotations about two different axes)")
    if mount == "fixed":
        A = inverse(A)
    elif mount != "hand":
        raise KincalError(f"mount={mount!r}: use 'hand' or 'fixed'")
    i, j = _pairs(len(A))
    i, j = np.r_[i, j], np.r_[j, i]           # both orientations: module docstring
    Ar = inverse(A[j]) @ A[i]
    Br = B[j] @ inverse(B[i])
    M = _left(quaternion(Ar[:, :3, :3])) - _right(quaternion(Br[:, :3, :3]))
    S = np.einsum("pki,pkj->ij", M, M)
    qx = np.linalg.eigh(S)[1][:, 0]
    w, v = qx[0], qx[1:]
    Rx = (w * w - v @ v) * np.eye(3) + 2.0 * np.outer(v, v) + 2.0 * w * np.array(
        [[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    C = Ar[:, :3, :3] - np.eye(3)
    d = np.einsum("ij,pj->pi", Rx, Br[:, :3, 3]) - Ar[:, :3, 3]
    N = np.einsum("pki,pkj->ij", C, C)
    if np.linalg.cond(N) > 1e12:
        raise IdentifiabilityError("the hand-eye translation cannot be found: the robot "
                                   "turned about one axis only")
    tx = np.linalg.solve(N, np.einsum("pki,pk->i", C, d))
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = Rx, tx
    rot_res = log_so3(Ar[:, :3, :3] @ Rx @ np.swapaxes(Rx @ Br[:, :3, :3], 1, 2))
    tr_res = np.einsum("pij,j->pi", C, tx) - d
    chain = A @ X @ B
    Z = average_pose(chain)
    return HandEye(X, Z, float(np.degrees(np.sqrt(np.mean(np.sum(rot_res**2, 1))))),
                   float(np.sqrt(np.mean(np.sum(tr_res**2, 1)))),
                   np.linalg.norm(chain[:, :3, 3] - Z[:3, 3], axis=1))


def robot_world(robot_poses: ArrayLike, board_poses: ArrayLike, mount: str = "hand"
                ) -> HandEye:
    """``X`` and ``Z`` together from the samples themselves (the robot-world form
    ``A_i X = Z B_i^-1``), no pairs: a closed form that uses every image once.

    Rotation: ``R_A R_X = R_Z R_B'`` (``B' = B^-1``) is linear in both,
    ``(I kron R_A) vec(R_X) - (R_B'^T kron I) vec(R_Z) = 0`` (column-major ``vec``); the
    stacked (9N, 18) system's right singular vector of the smallest singular value gives
    ``R_X`` and ``R_Z`` up to a common scale and sign, each projected on SO(3) by SVD
    (the sign from ``det``).  Translation: ``R_A t_X - t_Z = R_Z t_B' - t_A``, least
    squares over all samples (6 unknowns).  Sums over the samples: shuffling them changes
    nothing but the order of floating-point additions.  ``mount="fixed"`` inverts ``A`` as
    :func:`hand_eye` does.  Residuals are reported per sample in the pair fields'
    place: ``rotation_rms_deg`` the angle of ``R_A R_X (R_Z R_B')^T``,
    ``translation_rms`` the translation equation's residual [m].
    """
    A = _check(robot_poses, "robot poses")
    B = _check(board_poses, "board poses")
    if len(A) != len(B):
        raise KincalError(f"{len(A)} robot poses but {len(B)} board poses")
    if len(A) < 3:
        raise IdentifiabilityError(f"{len(A)} images: a hand-eye needs at least 3 poses")
    if mount == "fixed":
        A = inverse(A)
    elif mount != "hand":
        raise KincalError(f"mount={mount!r}: use 'hand' or 'fixed'")
    Bi = inverse(B)
    I3 = np.eye(3)
    M = np.concatenate([np.concatenate([np.kron(I3, a[:3, :3]), -np.kron(b[:3, :3].T, I3)],
                                       axis=1) for a, b in zip(A, Bi, strict=True)])
    v = np.linalg.eigh(M.T @ M)[1][:, 0]

    def so3(m: Array) -> Array:
        U, _, Vt = np.linalg.svd(m)
        return np.asarray(U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, dtype=float)

    mx = v[:9].reshape(3, 3, order="F")
    sign = 1.0 if np.linalg.det(mx) > 0 else -1.0
    Rx, Rz = so3(sign * mx), so3(sign * v[9:].reshape(3, 3, order="F"))
    C = np.concatenate([np.concatenate([a[:3, :3], -I3], axis=1) for a in A])
    d = np.concatenate([Rz @ b[:3, 3] - a[:3, 3] for a, b in zip(A, Bi, strict=True)])
    t = np.linalg.lstsq(C, d, rcond=None)[0]
    X, Z = np.eye(4), np.eye(4)
    X[:3, :3], X[:3, 3], Z[:3, :3], Z[:3, 3] = Rx, t[:3], Rz, t[3:]
    rot = log_so3(A[:, :3, :3] @ Rx @ np.swapaxes(Rz @ Bi[:, :3, :3], 1, 2))
    chain = A @ X @ B
    return HandEye(X, Z, float(np.degrees(np.sqrt(np.mean(np.sum(rot**2, 1))))),
                   float(np.sqrt(np.mean((C @ t - d) ** 2) * 3.0)),
                   np.linalg.norm(chain[:, :3, 3] - Z[:3, 3], axis=1))


def rotation_spread(robot_poses: ArrayLike) -> tuple[Array, Array]:
    """How much the flange turned about each principal axis, over all pairs of poses.

    With ``omega_ij = log(R_j^T R_i)`` (rotation vectors of the relative motions in the
    flange frame), ``S = mean omega omega^T``: returns ``sqrt`` of its eigenvalues
    (3,) [rad], largest first (the RMS rotation about each principal axis), and the
    axes as columns (3, 3) in the flange frame.
    """
    A = _check(robot_poses, "robot poses")
    i, j = _pairs(len(A))
    w = log_so3(np.swapaxes(A[j, :3, :3], 1, 2) @ A[i, :3, :3])
    lam, V = np.linalg.eigh(w.T @ w / max(len(w), 1))
    return np.sqrt(np.clip(lam[::-1], 0.0, None)), V[:, ::-1]


def _axis_name(v: Array, frame: str) -> str:
    k = int(np.argmax(np.abs(v)))
    if abs(v[k]) > 0.9:
        return f"the {frame}'s {'xyz'[k]} axis"
    return f"the {frame} direction ({v[0]:.2f}, {v[1]:.2f}, {v[2]:.2f})"


def check_rotations(robot_poses: ArrayLike, min_deg: float = 5.0, frame: str = "flange",
                    mount: str = "hand") -> Array:
    """Refuse (:class:`~kincal.errors.IdentifiabilityError`, one line) when the flange
    turned less than ``min_deg`` RMS about two independent axes: the hand-eye rotation and
    the translation along the missing axis cannot be seen.  Returns the RMS rotation
    about the principal axes [deg], largest first."""
    A = _check(robot_poses, "robot poses")
    if mount == "fixed":
        A = inverse(A)
    s, V = rotation_spread(A)
    deg = np.degrees(s)
    if deg[1] < min_deg:
        small = [f"{deg[k]:.2g} deg about {_axis_name(V[:, k], frame)}" for k in (1, 2)]
        raise IdentifiabilityError(
            f"rotations too small for a hand-eye: only {deg[0]:.3g} deg RMS about "
            f"{_axis_name(V[:, 0], frame)}, {'; '.join(small)} (need {min_deg:g} deg about "
            "two axes at least); add poses that tilt the hand about those axes")
    return np.asarray(deg, dtype=float)
