"""Static gravity torques of a serial chain from point masses riding on its links.

A link's mass ``m_i`` [kg] at its centre of mass ``c_i`` rides on the last joint before
it in the chain.  Gravity ``g`` [m/s^2] (a vector in the robot's reference frame, the
frame :meth:`~kincal.robots.chain.Robot.fk` is expressed in; default ``(0, 0, -9.81)``)
has the potential energy

    V(q) = - sum_i m_i g . c_i(q)                                   [J]

and exerts on joint ``j`` the generalised force

    tau_j = - dV/dq_j
          = a_j . sum_{i after j} (c_i - o_j) x (m_i g)              revolute  [N m]
          = a_j . sum_{i after j} m_i g                             prismatic [N]

with ``a_j`` the unit direction in which ``q_j`` turns / slides (the axis of the joint's
elementary transform times its sign ``s_j``) and ``o_j`` a point on that axis, both in
the reference frame.  ``tau`` is the *load* torque: the torque gravity applies to the
joint, positive in the direction of increasing ``q_j``.  The torque the joint's drive
must supply to hold the posture is ``-tau``.  A joint with compliance ``k_j`` [rad/(N m)
or m/N] therefore deflects in the direction of ``tau``: the link side sits at
``q_j + k_j tau_j`` while the motor-side encoder reads ``q_j`` (see
:class:`kincal.measure.joints.compliance.JointCompliance`).

Where a mass is given: :class:`PointMass` ``(joint, mass, com)`` with ``com`` [m] in the
frame just after joint ``joint``'s elementary transform ``X(c + s q)`` (the frame
:meth:`~kincal.robots.chain.Robot.frames` returns for that joint; for a URDF joint with
a coordinate axis it is the child link's frame), or in the reference frame when
``joint = -1`` (mass before the first joint: it loads no joint).
:func:`kincal.robots.urdf.load_urdf_inertials` reads these from a URDF's
``<inertial>`` elements.

Vectorised over the N configurations: one pass of the chain's frames, then a loop over
the n joints (never over configurations).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["PointMass", "STANDARD_GRAVITY", "gravity_torques"]

#: Gravity in a reference frame whose z axis points up [m/s^2].
STANDARD_GRAVITY = (0.0, 0.0, -9.81)

_AXIS = {"Rx": 0, "Ry": 1, "Rz": 2, "Tx": 0, "Ty": 1, "Tz": 2}


class PointMass(NamedTuple):
    """A mass riding on a joint of the chain.

    Attributes:
        joint: index into ``robot.joints`` of the last joint before the mass (the one
            whose motion carries it), or -1 for a mass before the first joint.
        mass: [kg], >= 0.
        com: centre of mass [m] in the frame just after that joint's elementary
            transform (``joint = -1``: in the robot's reference frame).
        name: where it comes from (e.g. the URDF link), for reports.
    """

    joint: int
    mass: float
    com: tuple[float, float, float]
    name: str = ""


def _chain_order(robot: Robot) -> tuple[list[int], list[int]]:
    """``(rank, carrier)``: per joint, its position along the chain (0 = nearest the
    base) and the index of the elementary transform that carries it."""
    carriers = [-1] * robot.n
    for k, et in enumerate(robot.ets):
        if et.joint >= 0:
            carriers[et.joint] = k
    by_place = sorted(range(robot.n), key=lambda j: carriers[j])
    rank = [0] * robot.n
    for r, j in enumerate(by_place):
        rank[j] = r
    return rank, carriers


def _check_masses(robot: Robot, masses: Sequence[PointMass | tuple[Any, ...]]) -> list[PointMass]:
    out = []
    for i, m in enumerate(masses):
        pm = PointMass(*m)
        if not (-1 <= int(pm.joint) < robot.n) or int(pm.joint) != pm.joint:
            raise KincalError(f"point mass {i} ({pm.name or 'unnamed'}): joint {pm.joint} is not "
                              f"a joint of robot {robot.name!r} (0 .. {robot.n - 1}, or -1)")
        com = np.asarray(pm.com, dtype=float)
        if com.shape != (3,) or not np.all(np.isfinite(com)):
            raise KincalError(f"point mass {i} ({pm.name or 'unnamed'}): the centre of mass "
                              "must be three finite numbers [m]")
        if not (np.isfinite(pm.mass) and pm.mass >= 0):
            raise KincalError(f"point mass {i} ({pm.name or 'unnamed'}): mass {pm.mass!r} must "
                              "be finite and >= 0 [kg]")
        out.append(PointMass(int(pm.joint), float(pm.mass), (com[0], com[1], com[2]), pm.name))
    return out


def gravity_torques(robot: Robot, q: ArrayLike, masses: Sequence[PointMass | tuple[Any, ...]],
                    g: ArrayLike = STANDARD_GRAVITY) -> Array:
    """Static gravity load ``tau = -dV/dq`` on every joint (see the module docstring).

    Args:
        robot: the chain (its current parameter values place the axes and masses).
        q: (N, n) joint configurations [rad / m], or (n,).
        masses: the :class:`PointMass` list (or plain ``(joint, mass, com)`` tuples).
        g: gravity [m/s^2] in the robot's reference frame (the frame of ``robot.fk``).

    Returns:
        (N, n) load torques [N m] (revolute joints) and forces [N] (prismatic joints),
        positive in the direction of increasing ``q_j``; (n,) for a single ``q``.
        With ``m_tot,j`` and ``h_j = sum m_i c_i`` the mass and first moment of
        everything after joint ``j`` (accumulated from the tip, each mass placed by the
        frame of its joint): revolute ``tau_j = a_j . ((h_j - m_tot,j o_j) x g)``,
        prismatic ``tau_j = m_tot,j (a_j . g)``.
    """
    q = np.asarray(q, dtype=float)
    single = q.ndim == 1
    q2 = np.atleast_2d(q)
    gv = np.asarray(g, dtype=float).reshape(-1)
    if gv.shape != (3,) or not np.all(np.isfinite(gv)):
        raise KincalError(f"gravity must be a finite 3-vector [m/s^2], got {g!r}")
    pms = _check_masses(robot, masses)
    n = robot.n
    rank, carriers = _chain_order(robot)
    F = robot.frames(q2)                                   # (N, n + 2, 4, 4)
    N = F.shape[0]
    # mass and first moment (local frame) riding on each joint, in chain order
    mass_on = np.zeros(n)
    moment_on = np.zeros((n, 3))
    for pm in pms:
        if pm.joint >= 0:
            r = rank[pm.joint]
            mass_on[r] += pm.mass
            moment_on[r] += pm.mass * np.asarray(pm.com)
    tau = np.zeros((N, n))
    m_tot = 0.0
    h_tot = np.zeros((N, 3))                               # first moment, reference frame
    order = sorted(range(n), key=lambda j: rank[j])
    for j in reversed(order):                              # from the tip to the base
        r = rank[j]
        R, p = F[:, r + 1, :3, :3], F[:, r + 1, :3, 3]
        m_tot += mass_on[r]
        h_tot += mass_on[r] * p + R @ moment_on[r]
        et = robot.ets[carriers[j]]
        a = et.scale * R[:, :, _AXIS[et.kind]]             # (N, 3) motion direction
        if et.is_rotation:
            tau[:, j] = np.einsum("ni,ni->n", a, np.cross(h_tot - m_tot * p, gv))
        else:
            tau[:, j] = m_tot * (a @ gv)
    return tau[0] if single else tau
