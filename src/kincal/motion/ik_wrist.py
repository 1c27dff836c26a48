"""Closed-form IK of industrial 6R arms with a spherical wrist (KUKA, ABB, FANUC, PUMA).

The family, in standard DH (``theta_i = q_i + theta_offset[i]``): ``alpha1, alpha3,
alpha4, alpha5 = +-90 deg``, ``alpha2 = 0`` (axes 2 and 3 parallel), ``a4 = a5 = d5 =
0`` (axes 4, 5, 6 meet in the wrist centre); ``a1, d1, d2, d3, a2, a3, d4, d6`` and the
last link's ``a6, alpha6`` are free, as are the base and tool frames.  The PUMA 560,
the KUKA KR 6, the ABB IRB 120 and FANUC's M-10iA built-ins are all in it.

Derivation (frame 1 = after link 1, ``e = -sin(alpha3) d4``, ``s1 = sin(alpha1)``).  The
wrist centre ``p_w = p - d6 z`` (after removing base, tool and the last link's
``Tx(a6) Rx(alpha6)``) is

    p_w = Rz(theta1) [a1 + u, -s1 w, 0] + [0, 0, d1 + s1 v],   w = d2 + d3,
    u = a2 c2 + a3 c23 - e s23,   v = a2 s2 + a3 s23 + e c23.

* shoulder: with ``(rho, phi)`` the polar coordinates of ``(p_wx, p_wy)``,
  ``sin(theta1 - phi) = s1 w / rho``: ``theta1 = phi + asin(s1 w / rho)`` (``a1 + u =
  +sqrt(rho^2 - w^2)``) or ``phi + pi - asin(s1 w / rho)`` (negative root);
  ``v = s1 (p_wz - d1)``;
* elbow: ``u^2 + v^2 = a2^2 + a3^2 + e^2 + 2 a2 (a3 c3 - e s3)``, so ``theta3 = -beta +-
  acos(K / r3)`` with ``K = (u^2 + v^2 - a2^2 - a3^2 - e^2) / (2 a2)``, ``r3 = |(a3,
  e)|``, ``beta = atan2(e, a3)``; then ``theta2 = atan2(v, u) - atan2(Y, X)``,
  ``X = a2 + a3 c3 - e s3``, ``Y = a3 s3 + e c3``;
* wrist: ``R_3^6 = R_3^T R = Rz(theta4) Rx(alpha4) Rz(theta5) Rx(alpha5) Rz(theta6)``.
  Since ``Rx(a) Rz(t) = Ry(-sin(a) t) Rx(a)``, ``M = R_3^6 Rx(alpha4 + alpha5)^T =
  Rz(theta4) Ry(sigma theta5) Rz(tau theta6)`` with ``sigma = -sin(alpha4)``,
  ``tau = cos(alpha4 + alpha5)``: a ZYZ decomposition with its two signs of the middle
  angle.  At ``sin(theta5) = 0`` only ``theta4 +- theta6`` is defined; ``theta4 = 0``.

:func:`arm_indicators` gives the three signed quantities that tell the branches apart
(they are also what robot controllers encode as a configuration): the shoulder
``a1 + u`` [m] (the wrist centre in front of or behind axis 1), the elbow ``Y`` [m]
(the wrist centre on either side of the line through axes 2 and 3) and
``sin(theta5)`` (the wrist).  Each vanishes at its singularity.  Units: m, rad.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.motion.ik_closed_form import (
    ClosedFormSolutions,
    NotThisFamily,
    _dh_table,
    _finish,
    _is,
    _poses,
    _require,
    _strip_frames,
)
from kincal.robots.chain import Robot
from kincal.robots.dh import DHLink
from kincal.spatial import rotx, rotz

Array = NDArray[np.float64]

__all__ = ["WRIST_BRANCHES", "arm_indicators", "check_wrist_family", "ik_spherical_wrist"]

#: Branch names in the order :func:`ik_spherical_wrist` returns them.
WRIST_BRANCHES = tuple(f"{s}/{e}/{w}" for s in ("front", "back") for e in ("first", "second")
                       for w in ("plus", "minus"))


def check_wrist_family(robot: Robot) -> list[DHLink]:
    """The robot's DH table, or :class:`NotThisFamily` naming what does not fit."""
    fam = "spherical-wrist 6R"
    L = _dh_table(robot, "RRRRRR", fam)
    for i in (0, 2, 3, 4):
        _require(_is(abs(L[i].alpha), 90), robot, f"alpha[{i + 1}] is not +-90 deg", fam)
    _require(_is(L[1].alpha, 0), robot, "alpha[2] is not 0", fam)
    for name, v in (("a[4]", L[3].a), ("a[5]", L[4].a), ("d[5]", L[4].d)):
        _require(abs(v) < 1e-12, robot, f"{name} is not 0", fam)
    _require(all(link.beta is None for link in L), robot, "it has Hayati twists", fam)
    _require(abs(L[1].a) > 1e-9, robot, "a[2] is zero", fam)
    return L


def _r03(L: list[DHLink], t1: Array, t23: Array) -> Array:
    return rotz(t1) @ rotx(L[0].alpha) @ rotz(t23) @ rotx(L[2].alpha)


def _wrist(M: Array, sigma: float, tau: float) -> tuple[tuple[Array, Array, Array], ...]:
    """Both ``(theta4, theta5, theta6)`` with ``M = Rz(t4) Ry(sigma t5) Rz(tau t6)``."""
    m13, m23, m33 = M[:, 0, 2], M[:, 1, 2], M[:, 2, 2]
    m31, m32 = M[:, 2, 0], M[:, 2, 1]
    sn = np.hypot(m13, m23)
    lock = sn < 1e-12
    up = np.arctan2(M[:, 1, 0], M[:, 0, 0])              # M = Rz(t4 + psi), cos = 1
    down = -np.arctan2(-M[:, 1, 0], -M[:, 0, 0])         # M = Rz(t4 - psi) Ry(pi)
    psi_lock = np.where(m33 > 0, up, down)
    out = []
    for sgn in (1.0, -1.0):
        th = np.arctan2(sgn * sn, m33)
        phi = np.where(lock, 0.0, np.arctan2(sgn * m23, sgn * m13))
        psi = np.where(lock, psi_lock, np.arctan2(sgn * m32, -sgn * m31))
        out.append((phi, sigma * th, tau * psi))
    return tuple(out)


def ik_spherical_wrist(robot: Robot, targets: ArrayLike) -> ClosedFormSolutions:
    """All 8 closed-form solutions for poses (N, 4, 4) [m]; branches :data:`WRIST_BRANCHES`.

    Branch order: shoulder (front: ``a1 + u > 0``, back) x elbow (the ``+acos`` and
    ``-acos`` roots) x wrist (the two signs of the ZYZ middle angle).  Values are
    wrapped to (-pi, pi] or moved by 2 pi into the joint limits where that fits.
    """
    L = check_wrist_family(robot)
    T = _strip_frames(robot, _poses(targets), L[5])
    N = T.shape[0]
    s1 = float(np.sin(L[0].alpha))
    a1, d1, a2, a3, d6 = L[0].a, L[0].d, L[1].a, L[2].a, L[5].d
    e = -float(np.sin(L[2].alpha)) * L[3].d
    w = L[1].d + L[2].d
    sigma = -float(np.sin(L[3].alpha))
    tau = float(np.round(np.cos(L[3].alpha + L[4].alpha)))
    R = T[:, :3, :3]
    pw = T[:, :3, 3] - d6 * R[:, :, 2]
    rho = np.hypot(pw[:, 0], pw[:, 1])
    phi = np.arctan2(pw[:, 1], pw[:, 0])
    ok_sh = rho >= abs(w)
    with np.errstate(invalid="ignore", divide="ignore"):
        asn = np.arcsin(np.clip(s1 * w / np.where(rho > 0, rho, np.inf), -1, 1))
    root = np.sqrt(np.maximum(rho**2 - w**2, 0.0))
    v = s1 * (pw[:, 2] - d1)
    theta = np.zeros((N, 8, 6))
    reach = np.zeros((N, 8), bool)
    r3 = np.hypot(a3, e)
    beta = np.arctan2(e, a3)
    post = rotx(L[3].alpha + L[4].alpha).T
    for s, (t1, r) in enumerate(((phi + asn, root), (phi + np.pi - asn, -root))):
        u = r - a1
        K = (u**2 + v**2 - a2**2 - a3**2 - e**2) / (2 * a2)
        ok_el = ok_sh & (np.abs(K) <= r3 * (1 + 1e-12))
        ac = np.arccos(np.clip(K / r3, -1, 1))
        for el, t3 in enumerate((-beta + ac, -beta - ac)):
            c3, s3 = np.cos(t3), np.sin(t3)
            X, Y = a2 + a3 * c3 - e * s3, a3 * s3 + e * c3
            t2 = np.arctan2(v, u) - np.arctan2(Y, X)
            M = np.swapaxes(_r03(L, t1, t2 + t3), 1, 2) @ R @ post
            for fl, (t4, t5, t6) in enumerate(_wrist(M, sigma, tau)):
                b = 4 * s + 2 * el + fl
                theta[:, b] = np.stack([t1, t2, t3, t4, t5, t6], 1)
                reach[:, b] = ok_el
    return _finish(robot, theta, reach, L, WRIST_BRANCHES)


def arm_indicators(robot: Robot, q: ArrayLike) -> Array:
    """``(a1 + u [m], Y [m], sin(theta5))`` at joint values q (N, 6) -> (N, 3).

    The signed distances that separate the 8 branches (module docstring): the wrist
    centre's reach in front of axis 1, its side of the line through axes 2 and 3
    (times the upper-arm length's sign), and the wrist flip.  Each is 0 at its
    singularity (wrist centre on axis 1, arm stretched or folded, axes 4 and 6 aligned).
    """
    try:
        L = check_wrist_family(robot)
    except NotThisFamily:
        raise
    qq = np.atleast_2d(np.asarray(q, dtype=float))
    th = qq + np.array([link.theta_offset for link in L])
    e = -float(np.sin(L[2].alpha)) * L[3].d
    a2, a3 = L[1].a, L[2].a
    t2, t3 = th[:, 1], th[:, 2]
    u = a2 * np.cos(t2) + a3 * np.cos(t2 + t3) - e * np.sin(t2 + t3)
    Y = (a3 * np.sin(t3) + e * np.cos(t3)) * np.sign(a2)
    return np.stack([L[0].a + u, Y, np.sin(th[:, 4])], 1)
