"""SE(3) / SO(3) helpers, batched over a leading axis.

Conventions (used everywhere in kincal):

* A homogeneous transform is a ``(4, 4)`` array, a batch is ``(N, 4, 4)``.
* Roll-pitch-yaw (URDF ``rpy``, extrinsic X-Y-Z = intrinsic Z-Y-X):
  ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``, stored as ``(roll, pitch, yaw)`` [rad].
* Euler ZYZ: ``R = Rz(phi) @ Ry(theta) @ Rz(psi)``, stored as ``(phi, theta, psi)`` [rad].
* A pose error / twist is a 6-vector ``[dp; dphi]``: translation [m] then a small
  rotation vector [rad], both expressed in the base frame.
* A *frame* given as six numbers (a robot's ``base.*`` / ``tool.*``, an instrument's
  ``tracker.*``, the ``instrument=`` of the simulators) is ordered as
  :data:`FRAME_FIELDS` ``(x, y, z, rz, ry, rx)`` with
  ``T = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` [m, rad]: the order in which the factors
  are applied.  :func:`matrix_from_frame` / :func:`frame_from_matrix` are the one pair
  of conversions; vendor orders (URDF ``rpy``, KUKA ``A B C``, FANUC ``W P R``) are
  converted by functions named for them.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError

Array = NDArray[np.float64]

#: Field order of a 6-number frame: ``T = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` [m, rad].
FRAME_FIELDS = ("x", "y", "z", "rz", "ry", "rx")


def rotx(angle: ArrayLike) -> Array:
    """Rotation about x by ``angle`` [rad]; scalar -> (3, 3), (N,) -> (N, 3, 3)."""
    a = np.asarray(angle, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1),
                     np.stack([z, s, c], -1)], -2)


def roty(angle: ArrayLike) -> Array:
    """Rotation about y by ``angle`` [rad]; scalar -> (3, 3), (N,) -> (N, 3, 3)."""
    a = np.asarray(angle, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                     np.stack([-s, z, c], -1)], -2)


def rotz(angle: ArrayLike) -> Array:
    """Rotation about z by ``angle`` [rad]; scalar -> (3, 3), (N,) -> (N, 3, 3)."""
    a = np.asarray(angle, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


def homogeneous(R: ArrayLike, p: ArrayLike) -> Array:
    """Build ``[[R, p], [0, 1]]`` from rotations (..., 3, 3) and positions (..., 3)."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def inverse(T: ArrayLike) -> Array:
    """Inverse of homogeneous transforms: ``[[R^T, -R^T p], [0, 1]]``."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return homogeneous(Rt, -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3]))


def skew(v: ArrayLike) -> Array:
    """Cross-product matrix ``[v]x`` with ``[v]x w = v x w``; (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def rpy_to_matrix(rpy: ArrayLike) -> Array:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` from ``(roll, pitch, yaw)`` [rad]; (..., 3)."""
    rpy = np.asarray(rpy, dtype=float)
    return rotz(rpy[..., 2]) @ roty(rpy[..., 1]) @ rotx(rpy[..., 0])


def matrix_to_rpy(R: ArrayLike) -> Array:
    """Inverse of :func:`rpy_to_matrix`; pitch in [-pi/2, pi/2].

    ``yaw = atan2(R21, R11)``; then ``M = Rz(-yaw) R = Ry(pitch) Rx(roll)`` gives
    ``pitch = atan2(-R31, M11)`` and ``roll = atan2(-M23, M22)``.  Removing yaw first
    keeps full accuracy near gimbal lock (pitch = +-pi/2), where yaw = 0 and roll
    absorbs the rotation about the vertical.
    """
    R = np.asarray(R, dtype=float)
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    cy, sy = np.cos(yaw), np.sin(yaw)
    m00 = cy * R[..., 0, 0] + sy * R[..., 1, 0]
    m11 = -sy * R[..., 0, 1] + cy * R[..., 1, 1]
    m12 = -sy * R[..., 0, 2] + cy * R[..., 1, 2]
    return np.stack([np.arctan2(-m12, m11), np.arctan2(-R[..., 2, 0], m00), yaw], -1)


def rpy_near(R: ArrayLike, near: ArrayLike, pole: float = 0.0) -> Array:
    """The ``(roll, pitch, yaw)`` [rad] of one rotation ``R`` (3, 3) closest to ``near``.

    ``R = Rz(yaw) Ry(pitch) Rx(roll)`` has two exact solutions, ``(r, p, y)`` from
    :func:`matrix_to_rpy` and ``(r + pi, pi - p, y + pi)``, each angle free by whole
    turns; the one with the least ``sum((angle - near)**2)`` is returned, so a small
    change of the rotation is a small change of the numbers wherever the numbers allow it.

    At gimbal lock (``|pitch| = pi/2``) only ``yaw - roll`` (pitch ``+pi/2``) or
    ``yaw + roll`` (pitch ``-pi/2``) is defined.  When the rotation lies within ``pole``
    [rad] of that lock (its tool x axis within ``pole`` of the vertical: ``pole`` is the
    resolution of the written angles, below which the file cannot tell), pitch is set
    to exactly ``+-pi/2`` and the defined sum or difference ``s`` is split evenly against
    ``near``: ``d = wrap(s - s_near)``, ``yaw = yaw_near + d/2``, ``roll = roll_near -+
    d/2`` (the least-squares split).  Off the lock the split is fixed by the rotation:
    a rotation whose x axis leaves the vertical by ``t`` in a new direction moves roll
    and yaw by that direction's angle, whatever the representation.
    """
    Rm = np.asarray(R, dtype=float)
    r0, p0, y0 = (float(v) for v in np.asarray(near, dtype=float))
    roll, pitch, yaw = (float(v) for v in matrix_to_rpy(Rm))
    two_pi = 2.0 * math.pi

    def closest(a: float, ref: float) -> float:
        return a + two_pi * round((ref - a) / two_pi)

    if math.pi / 2 - abs(pitch) <= pole:
        sign = 1.0 if pitch > 0 else -1.0
        # R Ry(-sign pi/2) = Rz(s) with s = yaw - sign * roll
        M = Rm @ roty(-sign * math.pi / 2)
        s = math.atan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])
        d = float(wrap_angle(s - (y0 - sign * r0)))
        return np.array([r0 - sign * d / 2, closest(sign * math.pi / 2, p0), y0 + d / 2])
    best: Array | None = None
    cost = math.inf
    for r, p, y in ((roll, pitch, yaw), (roll + math.pi, math.pi - pitch, yaw + math.pi)):
        cand = np.array([closest(r, r0), closest(p, p0), closest(y, y0)])
        c = float(np.sum((cand - np.array([r0, p0, y0])) ** 2))
        if c < cost:
            best, cost = cand, c
    assert best is not None
    return best


def quat_to_matrix(q: ArrayLike) -> Array:
    """Rotation of a quaternion ``[w, x, y, z]`` (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def zyz_to_matrix(zyz: ArrayLike) -> Array:
    """``R = Rz(phi) Ry(theta) Rz(psi)`` from ``(phi, theta, psi)`` [rad]; (..., 3)."""
    e = np.asarray(zyz, dtype=float)
    return rotz(e[..., 0]) @ roty(e[..., 1]) @ rotz(e[..., 2])


def matrix_to_zyz(R: ArrayLike) -> Array:
    """Inverse of :func:`zyz_to_matrix` with theta in [0, pi].

    ``theta = atan2(sqrt(R13^2 + R23^2), R33)``, ``phi = atan2(R23, R13)``,
    ``psi = atan2(R32, -R31)``.  At theta = 0 or pi, psi is set to 0.
    """
    R = np.asarray(R, dtype=float)
    st = np.hypot(R[..., 0, 2], R[..., 1, 2])
    theta = np.arctan2(st, R[..., 2, 2])
    lock = st < 1e-12
    # In the locks psi = 0: theta = 0 gives Rz(phi) (phi = atan2(R21, R11)); theta = pi
    # gives Rz(phi) Ry(pi) = [[-c, -s, 0], [-s, c, 0], [0, 0, -1]] (phi = atan2(-R21, -R11)).
    flip = np.where(R[..., 2, 2] < 0, -1.0, 1.0)
    phi = np.where(lock, np.arctan2(flip * R[..., 1, 0], flip * R[..., 0, 0]),
                   np.arctan2(R[..., 1, 2], R[..., 0, 2]))
    psi = np.where(lock, 0.0, np.arctan2(R[..., 2, 1], -R[..., 2, 0]))
    return np.stack([phi, theta, psi], -1)


def log_so3(R: ArrayLike) -> Array:
    """Rotation vector ``omega`` (axis * angle, [rad]) with ``exp([omega]x) = R``.

    ``w = vee(R - R^T) / 2 = sin(t) a`` and ``cos(t) = (tr R - 1) / 2`` give
    ``t = atan2(|w|, cos t)`` accurately over [0, pi].  Away from pi,
    ``omega = t w / sin t``.  Near pi (where ``|w|`` carries no direction) the axis
    comes from the symmetric part: ``(R + R^T)/2 - cos(t) I = (1 - cos t) a a^T``,
    its sign from ``w``.
    """
    R = np.asarray(R, dtype=float)
    w = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                  R[..., 1, 0] - R[..., 0, 1]], -1) / 2.0
    s = np.linalg.norm(w, axis=-1)
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    angle = np.arctan2(s, c)
    small = s < 1e-12
    factor = np.where(small, 1.0 + angle**2 / 6.0, angle / np.where(small, 1.0, s))
    out = np.array(w * factor[..., None])
    near_pi = c < -0.99
    if np.any(near_pi):
        Rn, cn, wn, tn = R[near_pi], c[near_pi], w[near_pi], angle[near_pi]
        S = (Rn + np.swapaxes(Rn, -1, -2)) / 2.0 - cn[:, None, None] * np.eye(3)
        S /= (1.0 - cn)[:, None, None]                       # = a a^T
        k = np.argmax(np.diagonal(S, axis1=-2, axis2=-1), axis=-1)
        idx = np.arange(S.shape[0])
        axis = S[idx, :, k] / np.sqrt(S[idx, k, k])[:, None]
        sign = np.where(np.einsum("ij,ij->i", axis, wn) < 0, -1.0, 1.0)
        out[near_pi] = axis * (sign * tn)[:, None]
    return out


def exp_so3(omega: ArrayLike) -> Array:
    """Rodrigues: ``R = I + sin(t)/t [w]x + (1 - cos(t))/t^2 [w]x^2`` with t = |w|."""
    w = np.asarray(omega, dtype=float)
    t = np.linalg.norm(w, axis=-1)
    K = skew(w)
    small = t < 1e-8
    ts = np.where(small, 1.0, t)
    a = np.where(small, 1.0 - t**2 / 6.0, np.sin(ts) / ts)
    b = np.where(small, 0.5 - t**2 / 24.0, (1.0 - np.cos(ts)) / ts**2)
    R: Array = np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)
    return R


def pose_error(T_target: ArrayLike, T_actual: ArrayLike) -> Array:
    """6-vector error ``[p_t - p_a; log(R_t R_a^T)]`` in the base frame, (..., 6).

    Zero when the poses coincide; to first order equals the geometric-Jacobian
    twist that moves ``T_actual`` onto ``T_target``.
    """
    Tt = np.asarray(T_target, dtype=float)
    Ta = np.asarray(T_actual, dtype=float)
    dp = Tt[..., :3, 3] - Ta[..., :3, 3]
    dR = Tt[..., :3, :3] @ np.swapaxes(Ta[..., :3, :3], -1, -2)
    return np.concatenate([dp, log_so3(dR)], -1)


def matrix_from_frame(values: ArrayLike) -> Array:
    """``T = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` from ``(x, y, z, rz, ry, rx)`` [m, rad].

    ``values`` is (..., 6) in :data:`FRAME_FIELDS` order; returns (..., 4, 4).
    """
    v = np.asarray(values, dtype=float)
    if v.shape == (6,):                     # one frame: no batched stacking (the same products)
        x, y, z, rz, ry, rx = v.tolist()
        cz, sz, cy, sy, cx, sx = (math.cos(rz), math.sin(rz), math.cos(ry), math.sin(ry),
                                  math.cos(rx), math.sin(rx))
        T = np.eye(4)
        T[:3, :3] = (np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
                     @ np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
                     @ np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]]))
        T[:3, 3] = x, y, z
        return T
    return homogeneous(rpy_to_matrix(v[..., [5, 4, 3]]), v[..., :3])


def frame_from_matrix(T: ArrayLike) -> Array:
    """Inverse of :func:`matrix_from_frame`: (..., 4, 4) -> ``(x, y, z, rz, ry, rx)``.

    The angles are those of :func:`matrix_to_rpy` (``ry`` in [-pi/2, pi/2]).
    """
    T = np.asarray(T, dtype=float)
    rpy = matrix_to_rpy(T[..., :3, :3])
    return np.concatenate([T[..., :3, 3], rpy[..., ::-1]], -1)


def xyzrpy_to_matrix(v: ArrayLike) -> Array:
    """``Trans(x, y, z) Rz(yaw) Ry(pitch) Rx(roll)`` from ``(x, y, z, roll, pitch, yaw)``
    (..., 6): URDF's ``xyz`` then ``rpy``, not :data:`FRAME_FIELDS`."""
    v = np.asarray(v, dtype=float)
    return homogeneous(rpy_to_matrix(v[..., 3:6]), v[..., :3])


def matrix_to_xyzrpy(T: ArrayLike) -> Array:
    """Inverse of :func:`xyzrpy_to_matrix`: (..., 4, 4) -> (..., 6) [m, rad]."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[..., :3, 3], matrix_to_rpy(T[..., :3, :3])], -1)


def rate_matrix(angles: ArrayLike, representation: str) -> Array:
    """Matrix ``E(phi)`` with ``omega = E(phi) phi_dot`` (angular velocity in the base frame).

    * ``"rpy"``, angles ``(roll, pitch, yaw)``:
      ``E = [[cy cp, -sy, 0], [sy cp, cy, 0], [-sp, 0, 1]]`` (columns: roll, pitch, yaw rates).
    * ``"zyz"``, angles ``(phi, theta, psi)``:
      ``E = [[0, -s_phi, c_phi s_theta], [0, c_phi, s_phi s_theta], [1, 0, c_theta]]``.

    Singular (det E = 0) at pitch = +-pi/2 (rpy) or theta = 0, pi (zyz).
    """
    a = np.asarray(angles, dtype=float)
    z, o = np.zeros(a.shape[:-1]), np.ones(a.shape[:-1])
    if representation == "rpy":
        cp, sp = np.cos(a[..., 1]), np.sin(a[..., 1])
        cy, sy = np.cos(a[..., 2]), np.sin(a[..., 2])
        rows = [[cy * cp, -sy, z], [sy * cp, cy, z], [-sp, z, o]]
    elif representation == "zyz":
        cf, sf = np.cos(a[..., 0]), np.sin(a[..., 0])
        ct, st = np.cos(a[..., 1]), np.sin(a[..., 1])
        rows = [[z, -sf, cf * st], [z, cf, sf * st], [o, z, ct]]
    else:
        raise KincalError(f"unknown orientation representation {representation!r}; "
                          "use 'rpy' or 'zyz'")
    return np.stack([np.stack(r, -1) for r in rows], -2)


def matrix_to_angles(R: ArrayLike, representation: str) -> Array:
    """Minimal orientation angles of ``R`` for ``representation`` in {"rpy", "zyz"}."""
    if representation == "rpy":
        return matrix_to_rpy(R)
    if representation == "zyz":
        return matrix_to_zyz(R)
    raise KincalError(f"unknown orientation representation {representation!r}; "
                      "use 'rpy' or 'zyz'")


def wrap_angle(a: ArrayLike) -> NDArray[np.float64]:
    """Angles wrapped to (-pi, pi]: ``pi - ((pi - a) mod 2 pi)`` [rad]."""
    return np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2 * np.pi)
