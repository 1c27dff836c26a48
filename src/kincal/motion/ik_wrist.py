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
    _dh_table,
    _finish,
    _is,
    _poses,
    _require,
    _strip_frames,
    spherical_wrist_angles,
)
from kincal.robots.chain import Robot
from kincal.robots.dh import DHLink

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


def ik_spherical_wrist(robot: Robot, targets: ArrayLike) -> ClosedFormSolutions:
    """All 8 closed-form solutions for poses (N, 4, 4) [m]; branches :data:`WRIST_BRANCHES`.

    Branch order: shoulder (front: ``a1 + u > 0``, back) x elbow (the ``+acos`` and
    ``-acos`` roots) x wrist (the two signs of the ZYZ middle angle).  Values are
    wrapped to (-pi, pi] or moved by 2 pi into the joint limits where that fits.
    """
    L = check_wrist_family(robot)
    theta, reach = spherical_wrist_angles(L, _strip_frames(robot, _poses(targets), L[5]))
    return _finish(robot, theta, reach, L, WRIST_BRANCHES)


def arm_indicators(robot: Robot, q: ArrayLike) -> Array:
    """``(a1 + u [m], Y [m], sin(theta5))`` at joint values q (N, 6) -> (N, 3).

    The signed distances that separate the 8 branches (module docstring): the wrist
    centre's reach in front of axis 1, its side of the line through axes 2 and 3
    (times the upper-arm length's sign), and the wrist flip.  Each is 0 at its
    singularity (wrist centre on axis 1, arm stretched or folded, axes 4 and 6 aligned).
    """
    L = check_wrist_family(robot)
    qq = np.atleast_2d(np.asarray(q, dtype=float))
    th = qq + np.array([link.theta_offset for link in L])
    e = -float(np.sin(L[2].alpha)) * L[3].d
    a2, a3 = L[1].a, L[2].a
    t2, t3 = th[:, 1], th[:, 2]
    u = a2 * np.cos(t2) + a3 * np.cos(t2 + t3) - e * np.sin(t2 + t3)
    Y = (a3 * np.sin(t3) + e * np.cos(t3)) * np.sign(a2)
    return np.stack([L[0].a + u, Y, np.sin(th[:, 4])], 1)
