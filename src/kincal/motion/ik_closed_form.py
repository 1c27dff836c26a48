"""Closed-form inverse kinematics for three robot families, batched over targets.

Each solver reads the robot's current DH table (:func:`kincal.robots.dh.dh_links`),
checks that its structure is the one the formulas assume, removes the base frame,
the tool frame and any constant trailing factor of the last link, and returns every
branch for every target as a :class:`ClosedFormSolutions`:

* :func:`ik_puma560` - 6R with a PUMA-560 geometry (alpha = 90, 0, -90, 90, -90, 0
  deg; a1 = a4 = a5 = d5 = 0; spherical wrist): 8 branches (shoulder left/right x
  elbow up/down x wrist flip).
* :func:`ik_spherical_rrp` - the spherical RRP arm of the spherical-manipulator report
  (alpha1 = -90, alpha2 = +90 deg, a1 = a2 = a3 = 0, prismatic third joint): position
  only, 4 branches (shoulder x sign of the stroke).
* :func:`ik_scara` - RRPR SCARA (alpha1 = 0, alpha2 = 0 or 180 deg, alpha3 = 0,
  a3 = 0, parallel vertical axes): 2 branches (elbow left/right).

``reachable`` says where the geometry admits a branch; ``within_limits`` where it also
respects the joint limits.  Revolute results are wrapped to (-pi, pi], or moved by
2 pi into the joint limits where that fits.  Units: m, rad.
The formulas are derived in each function's docstring; they are independent of the
numerical solver in :mod:`kincal.motion.ik`, which the tests cross-check against them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.robots.chain import Robot
from kincal.robots.dh import DHLink, dh_links
from kincal.spatial import inverse, matrix_from_frame, rotx, wrap_angle

Array = NDArray[np.float64]
_ANGLE_TOL = 1e-9


@dataclass(frozen=True)
class ClosedFormSolutions:
    """All closed-form branches for N targets.

    Attributes:
        q: (N, B, n) joint values [rad / m] per target and branch (NaN where unreachable).
        reachable: (N, B) the branch exists for the target's geometry.
        within_limits: (N, B) reachable and inside the joint limits.
        branches: B names, e.g. ``"left/up/noflip"``.
    """

    q: Array
    reachable: NDArray[np.bool_]
    within_limits: NDArray[np.bool_]
    branches: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.q.shape[0])


# ---------------------------------------------------------------------------
# helpers


_wrap = wrap_angle   # (-pi, pi]


def _is(angle: float, value_deg: float) -> bool:
    return abs(_wrap(np.array(angle - np.deg2rad(value_deg))).item()) < _ANGLE_TOL


class NotThisFamily(KincalError):
    """The robot's structure is not the one a closed-form solver assumes."""


def _require(ok: bool, robot: Robot, what: str, family: str) -> None:
    if not ok:
        raise NotThisFamily(f"robot {robot.name!r}: no {family} closed-form IK ({what})")


def _dh_table(robot: Robot, kinds: str, family: str) -> list[DHLink]:
    if robot.meta.get("convention") != "standard_dh":
        raise NotThisFamily(f"robot {robot.name!r}: the {family} closed-form IK needs a "
                            f"standard-DH robot (convention is "
                            f"{robot.meta.get('convention')!r})")
    links = dh_links(robot)
    got = "".join("R" if L.joint == "revolute" else "P" for L in links)
    _require(got == kinds, robot, f"joints are {got}, not {kinds}", family)
    return links


def _strip_frames(robot: Robot, T: Array, last: DHLink) -> Array:
    """``B^-1 T Tool^-1 (Tx(a_n) Rx(alpha_n))^-1``: the targets of the frame after Tz(d_n)."""
    B = matrix_from_frame(robot.frame_parameters("base"))
    tool = matrix_from_frame(robot.frame_parameters("tool"))
    tail = np.eye(4)
    tail[:3, :3] = rotx(last.alpha)
    tail[0, 3] = last.a
    return inverse(B) @ T @ inverse(tool) @ inverse(tail)


def _poses(targets: ArrayLike) -> Array:
    T = np.asarray(targets, dtype=float)
    if T.shape[-2:] != (4, 4):
        raise KincalError(f"closed-form IK targets must be poses (N, 4, 4); got {T.shape}")
    return T.reshape(-1, 4, 4)


def _limits_ok(robot: Robot, q: Array, reachable: NDArray[np.bool_]) -> NDArray[np.bool_]:
    lim = robot.joint_limits
    with np.errstate(invalid="ignore"):
        inside: NDArray[np.bool_] = np.all((q >= lim[:, 0] - 1e-12) & (q <= lim[:, 1] + 1e-12),
                                           axis=-1)
    return reachable & inside


def _finish(robot: Robot, theta: Array, reachable: NDArray[np.bool_], links: list[DHLink],
            names: tuple[str, ...]) -> ClosedFormSolutions:
    """Joint values from DH angles (q = theta - offset; prismatic q already solved).

    Revolute values are wrapped to (-pi, pi], then moved by 2 pi when that brings a value
    outside the limits inside them (limits such as [-45, 225] deg are not centred on 0).
    """
    q = theta.copy()
    lim = robot.joint_limits
    for i, L in enumerate(links):
        if L.joint == "revolute":
            qi = _wrap(theta[..., i] - L.theta_offset)
            lo, hi = lim[i]
            if np.isfinite(lo):
                shifted = lo + np.mod(qi - lo, 2 * np.pi)
                qi = np.where(((qi < lo) | (qi > hi)) & (shifted <= hi), shifted, qi)
            q[..., i] = qi
    q[~reachable] = np.nan
    return ClosedFormSolutions(q, reachable, _limits_ok(robot, q, reachable), names)


# ---------------------------------------------------------------------------
# PUMA 560


PUMA_BRANCHES = tuple(f"{s}/{e}/{w}" for s in ("left", "right") for e in ("up", "down")
                      for w in ("noflip", "flip"))
#: PUMA branches from :func:`spherical_wrist_angles`' (noflip, theta5 >= 0, is its second).
_PUMA_ORDER = [1, 0, 3, 2, 5, 4, 7, 6]


def _check_puma(robot: Robot) -> list[DHLink]:
    fam = "PUMA-560"
    L = _dh_table(robot, "RRRRRR", fam)
    want = (90, 0, -90, 90, -90)
    for i, w in enumerate(want):
        _require(_is(L[i].alpha, w), robot, f"alpha[{i + 1}] is not {w} deg", fam)
    for i in (0, 3, 4):
        _require(abs(L[i].a) < 1e-12, robot, f"a[{i + 1}] is not 0", fam)
    _require(abs(L[4].d) < 1e-12, robot, "d[5] is not 0", fam)
    _require(abs(L[1].a) > 1e-9 and np.hypot(L[2].a, L[3].d) > 1e-9, robot,
             "a[2] or the forearm is zero", fam)
    return L


def ik_puma560(robot: Robot, targets: ArrayLike) -> ClosedFormSolutions:
    """All 8 closed-form solutions of a PUMA-560-like 6R arm for poses (N, 4, 4).

    With ``theta_i = q_i + theta_offset[i]``, after removing the base, the tool and
    the constant ``Tx(a6) Rx(alpha6)`` of the last link, the wrist centre is
    ``p_w = p - d6 z6`` and equals ``[c1 u + s1 w, s1 u - c1 w, d1 + v]`` with
    ``w = d2 + d3``, ``u = a2 c2 + a3 c23 - d4 s23``, ``v = a2 s2 + a3 s23 + d4 c23``.

    * shoulder: ``rho sin(theta1 - phi) = w`` with ``(rho, phi)`` polar coordinates of
      ``(p_wx, p_wy)``: ``theta1 = phi + asin(w / rho)`` (left) or
      ``phi + pi - asin(w / rho)`` (right), and ``u = +-sqrt(rho^2 - w^2)``;
    * elbow: ``u^2 + v^2 = a2^2 + a3^2 + d4^2 + 2 a2 (a3 c3 - d4 s3)``, so
      ``theta3 = -beta +- acos(K / sqrt(a3^2 + d4^2))`` with ``beta = atan2(d4, a3)``;
    * ``theta2 = atan2(v, u) - atan2(Y, X)``, ``X = a2 + a3 c3 - d4 s3``,
      ``Y = a3 s3 + d4 c3``;
    * wrist: ``R_3^6 = R_3^T R = Rz(theta4) Ry(-theta5) Rz(theta6)`` (ZYZ):
      ``theta5 = atan2(+-sqrt(r13^2 + r23^2), r33)``, ``theta4 = atan2(-r23, -r13)``,
      ``theta6 = atan2(-r32, r31)`` for ``s5 > 0`` (signs reversed for ``s5 < 0``).
      At ``s5 = 0`` only ``theta4 +- theta6`` is defined; ``theta4 = 0`` is chosen.

    Branch order: shoulder (left, right) x elbow (up, down) x wrist (noflip, flip).
    The PUMA is a member of the spherical-wrist family: the angles are those of
    :func:`spherical_wrist_angles` (its wrist pair in the other order).
    """
    L = _check_puma(robot)
    theta, reach = spherical_wrist_angles(L, _strip_frames(robot, _poses(targets), L[5]))
    return _finish(robot, theta[:, _PUMA_ORDER], reach[:, _PUMA_ORDER], L, PUMA_BRANCHES)


def _rz_rx(t: Array, alpha: float) -> Array:
    """``Rz(t) Rx(alpha)`` (N, 3, 3), the rotation of a standard-DH link."""
    c, s = np.cos(t), np.sin(t)
    ca, sa = np.cos(alpha), np.sin(alpha)
    z = np.zeros_like(c)
    return np.stack([np.stack([c, -s * ca, s * sa], -1), np.stack([s, c * ca, -c * sa], -1),
                     np.stack([z, z + sa, z + ca], -1)], -2)


def _r03(L: list[DHLink], t1: Array, t23: Array) -> Array:
    """Rotation of frame 3: ``Rz(t1) Rx(alpha1) Rz(t2 + t3) Rx(alpha3)`` (alpha2 = 0)."""
    return _rz_rx(t1, L[0].alpha) @ _rz_rx(t23, L[2].alpha)


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


def spherical_wrist_angles(L: list[DHLink], T: Array
                           ) -> tuple[Array, NDArray[np.bool_]]:
    """DH angles ``theta`` (N, 8, 6) and ``reachable`` (N, 8) of a 6R arm with a spherical
    wrist (the family and derivation of :mod:`kincal.motion.ik_wrist`) for targets T
    (N, 4, 4) of the frame after ``Tz(d6)`` (:func:`_strip_frames`).

    Branch order: shoulder (``a1 + u > 0``, ``< 0``) x elbow (``+acos``, ``-acos``) x
    wrist (the two signs of the ZYZ middle angle).
    """
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
    return theta, reach


# ---------------------------------------------------------------------------
# spherical RRP arm (the spherical-manipulator report)


RRP_BRANCHES = ("left/out", "left/in", "right/out", "right/in")


def ik_spherical_rrp(robot: Robot, targets: ArrayLike) -> ClosedFormSolutions:
    """The 4 closed-form solutions of the spherical RRP arm for positions (N, 3) or poses.

    Standard DH with ``alpha1 = -90 deg``, ``alpha2 = +90 deg``, ``a1 = a2 = a3 = 0``,
    joint 3 prismatic (``d3 = q3 + d[3]``); the tool frame may rotate but not
    translate.  The position is (the spherical-manipulator report, plus a base height ``d1``)

        p = [c1 s2 d3 - d2 s1,  s1 s2 d3 + d2 c1,  d1 + c2 d3].

    ``-s1 p_x + c1 p_y = d2`` gives ``theta1 = phi - asin(d2 / rho)`` or
    ``phi - pi + asin(d2 / rho)`` (``rho, phi`` polar coordinates of ``p_x, p_y``);
    then ``u = s2 d3 = c1 p_x + s1 p_y``, ``d3 = +-sqrt(u^2 + (p_z - d1)^2)`` and
    ``theta2 = atan2(u / d3, (p_z - d1) / d3)``.  Reachable where ``rho >= |d2|``.
    Branch order: (left, right) shoulder x (out: d3 >= 0, in: d3 < 0).
    """
    fam = "spherical RRP"
    L = _dh_table(robot, "RRP", fam)
    _require(_is(L[0].alpha, -90) and _is(L[1].alpha, 90), robot,
             "alpha[1], alpha[2] are not -90, +90 deg", fam)
    _require(max(abs(L[0].a), abs(L[1].a), abs(L[2].a)) < 1e-12, robot, "a[1..3] are not 0",
             fam)
    tool = robot.frame_parameters("tool")
    _require(bool(np.all(np.abs(tool[:3]) < 1e-12)), robot, "the tool frame translates", fam)
    t = np.asarray(targets, dtype=float)
    p = t[..., :3, 3].reshape(-1, 3) if t.shape[-2:] == (4, 4) else t.reshape(-1, 3)
    B = matrix_from_frame(robot.frame_parameters("base"))
    p = (p - B[:3, 3]) @ B[:3, :3]
    d1, d2 = L[0].d, L[1].d
    rho, phi = np.hypot(p[:, 0], p[:, 1]), np.arctan2(p[:, 1], p[:, 0])
    ok = rho >= abs(d2) * (1 - 1e-15)
    asn = np.arcsin(np.clip(d2 / np.where(rho > 0, rho, np.inf), -1, 1))
    z = p[:, 2] - d1
    N = p.shape[0]
    theta = np.zeros((N, 4, 3))
    for s, t1 in enumerate((phi - asn, phi - np.pi + asn)):
        u = np.cos(t1) * p[:, 0] + np.sin(t1) * p[:, 1]
        r = np.hypot(u, z)
        for k, d3 in enumerate((r, -r)):
            with np.errstate(invalid="ignore", divide="ignore"):
                t2 = np.where(r > 0, np.arctan2(u / np.where(r > 0, d3, 1), z / np.where(
                    r > 0, d3, 1)), 0.0)
            theta[:, 2 * s + k] = np.stack([t1, t2, d3 - L[2].d], 1)
    reach = np.repeat(ok[:, None], 4, axis=1)
    return _finish(robot, theta, reach, L, RRP_BRANCHES)


# ---------------------------------------------------------------------------
# SCARA (RRPR)


SCARA_BRANCHES = ("right", "left")


def ik_scara(robot: Robot, targets: ArrayLike) -> ClosedFormSolutions:
    """The 2 closed-form solutions of an RRPR SCARA for poses (N, 4, 4).

    Standard DH with ``alpha1 = 0``, ``alpha2 = 0 or 180 deg`` (``c = cos alpha2 = +-1``),
    ``alpha3 = 0``, ``a3 = 0``.  After removing base, tool and the constant tail of
    link 4: ``R = Rz(theta1 + theta2 + c (theta3 + theta4)) Rx(alpha2)`` (``theta3``
    the constant offset of the prismatic joint) and

        p = [a1 c1 + a2 c12,  a1 s1 + a2 s12,  d1 + d2 + c (d3 + d4)].

    Planar 2R: ``c2 = (x^2 + y^2 - a1^2 - a2^2) / (2 a1 a2)``, ``theta2 = +-acos(c2)``,
    ``theta1 = atan2(y, x) - atan2(a2 s2, a1 + a2 c2)``; the stroke
    ``q3 = c (p_z - d1 - d2) - d4 - d[3]``; ``theta4 = c (psi - theta1 - theta2) -
    theta3`` with ``psi = atan2(R21, R11)`` of ``R Rx(alpha2)^T``.  Reachable where
    ``|c2| <= 1`` and the tool z axis is parallel to the joint axes (within 1e-9 rad).
    Branch order: right (theta2 >= 0), left.
    """
    fam = "SCARA"
    L = _dh_table(robot, "RRPR", fam)
    _require(_is(L[0].alpha, 0), robot, "alpha[1] is not 0", fam)
    c = 1.0 if _is(L[1].alpha, 0) else (-1.0 if _is(L[1].alpha, 180) else 0.0)
    _require(c != 0.0, robot, "alpha[2] is not 0 or 180 deg", fam)
    _require(_is(L[2].alpha, 0) and abs(L[2].a) < 1e-12, robot, "alpha[3] or a[3] is not 0",
             fam)
    T = _strip_frames(robot, _poses(targets), L[3])
    a1, a2 = L[0].a, L[1].a
    R = T[:, :3, :3] @ rotx(L[1].alpha).T
    x, y = T[:, 0, 3], T[:, 1, 3]
    c2 = (x**2 + y**2 - a1**2 - a2**2) / (2 * a1 * a2)
    tilt = np.arctan2(np.hypot(R[:, 0, 2], R[:, 1, 2]), R[:, 2, 2])
    ok = (np.abs(c2) <= 1 + 1e-12) & (tilt <= _ANGLE_TOL)
    psi = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    N = T.shape[0]
    theta = np.zeros((N, 2, 4))
    q3 = c * (T[:, 2, 3] - L[0].d - L[1].d) - L[3].d - L[2].d
    for b, sgn in enumerate((1.0, -1.0)):
        t2 = sgn * np.arccos(np.clip(c2, -1, 1))
        t1 = np.arctan2(y, x) - np.arctan2(a2 * np.sin(t2), a1 + a2 * np.cos(t2))
        t4 = c * (psi - t1 - t2) - L[2].theta_offset
        theta[:, b] = np.stack([t1, t2, q3, t4], 1)
    reach = np.repeat(ok[:, None], 2, axis=1)
    return _finish(robot, theta, reach, L, SCARA_BRANCHES)


# ---------------------------------------------------------------------------
# dispatch


SOLVERS: dict[str, Callable[[Robot, ArrayLike], ClosedFormSolutions]] = {
    "puma560": ik_puma560, "spherical_rrp": ik_spherical_rrp, "scara": ik_scara}


def closed_form_ik(robot: Robot, targets: ArrayLike) -> ClosedFormSolutions:
    """The closed-form solutions of whichever family ``robot`` belongs to.

    Tries the PUMA-560, spherical-RRP and SCARA structures in turn; raises a
    :class:`KincalError` naming the robot when none fits.
    """
    for solver in SOLVERS.values():
        try:
            return solver(robot, targets)
        except NotThisFamily:
            continue
    raise NotThisFamily(f"robot {robot.name!r} has no closed-form IK in kincal (closed forms "
                        f"exist for {', '.join(SOLVERS)}-type arms); use the numerical solver")
