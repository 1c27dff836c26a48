"""Joint compliance: each joint yields in proportion to its static gravity load.

The simplest physical model of gear and harmonic-drive elasticity, or of backlash
preloaded by gravity (the dual-SCARA thesis's non-geometric errors, "level 3"), is a linear torsion
(or axial) spring at each joint: the link side sits at

    q_eff = q + k (.) tau(q)

where ``q`` [rad / m] is the motor-side encoder reading, ``tau`` [N m / N] the static
load on the joint (:func:`kincal.robots.gravity.gravity_torques`: the torque gravity
applies, positive along ``+q``) and ``k`` [rad/(N m) or m/N] the compliance.
:class:`JointCompliance` is the :class:`~kincal.measure.joints.deflection.JointDeflection`
with regressor ``u = tau`` and parameters ``{name}.k[<joint>]``; the Jacobians, the
nesting and the one-configuration-per-residual rule are described there.

The loads are computed once, from the nominal robot and the measured readings, and
held fixed: a calibration moves the geometry by millimetres, which changes the loads
by a relative ``1e-3`` or so, a second-order effect on ``k tau``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.measure.base import MeasurementModel
from kincal.measure.joints.deflection import JointDeflection
from kincal.robots.chain import Robot
from kincal.robots.gravity import STANDARD_GRAVITY, PointMass, gravity_torques

Array = NDArray[np.float64]

__all__ = ["JointCompliance", "compliance_unit"]


def compliance_unit(kind: str) -> str:
    """Unit of a compliance: ``rad/(N m)`` for revolute joints, ``m/N`` for prismatic."""
    return "rad/(N m)" if kind == "revolute" else "m/N"


class JointCompliance(JointDeflection):
    """Evaluate ``block`` at ``q + k (.) tau`` and estimate the joint compliances ``k``.

    Args:
        block: the inner measurement block (its ``q`` are the encoder readings).
        robot: the robot the block measures (its joint names and kinds; the robot
            passed to :meth:`evaluate` must have the same joints).
        torques: (N, n) loads on every joint of ``robot`` at the N configurations
            [N m / N], or a callable ``torques(q) -> (N, n)`` evaluated once on
            ``block.q``.  See :meth:`gravity` for gravity loads.
        joints: names of the joints that get a compliance (default: all).

    Parameters: the inner block's, then ``{name}.k[<joint>]`` per joint in
    ``joints`` [rad/(N m) or m/N], role ``"compliance"``, initial value 0.  The block's
    ``name`` is the inner block's.
    """

    SYMBOL = "k"
    ROLE = "compliance"
    WHAT = "joint compliance"
    REGRESSOR = "loads"

    def __init__(self, block: MeasurementModel, robot: Robot,
                 torques: ArrayLike | Callable[[Array], ArrayLike],
                 joints: Sequence[str] | None = None) -> None:
        q = np.asarray(block.q, dtype=float)
        super().__init__(block, robot, torques(q) if callable(torques) else torques, joints)
        #: the link masses of :meth:`gravity` loads (empty for loads given directly)
        self.masses: list[PointMass] = []

    @classmethod
    def gravity(cls, block: MeasurementModel, robot: Robot, masses: Sequence[PointMass],
                joints: Sequence[str] | None = None, g: ArrayLike = STANDARD_GRAVITY
                ) -> JointCompliance:
        """Compliance under gravity: loads ``gravity_torques(robot, block.q, masses, g)``.

        ``masses`` e.g. from :func:`kincal.robots.urdf.load_urdf_inertials`; ``g``
        [m/s^2] in the robot's reference frame.
        """
        out = cls(block, robot, gravity_torques(robot, block.q, masses, g), joints)
        out.masses = list(masses)            # written with the calibrated robot
        return out

    @property
    def torques(self) -> Array:
        """(N, n) loads [N m / N] the compliances multiply."""
        return self.regressor

    def unit(self, kind: str) -> str:
        return compliance_unit(kind)
