"""One batched inverse-kinematics problem: targets, task mask and joint limits.

The error of configuration ``q`` against target ``(p_t, R_t)`` is
``e = [p_t - p(q); log(R_t R(q)^T)]`` (m, rad), restricted to the rows of the mask;
its Jacobian is the robot's geometric Jacobian on the same rows.  Used by
:func:`kincal.motion.ik.solve_ik` and its restart pool.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kincal.motion.joint_limits import project_to_limits
from kincal.robots.chain import Robot
from kincal.spatial import log_so3

Array = NDArray[np.float64]

__all__ = ["IKProblem"]


@dataclass
class IKProblem:
    """Targets, mask and joint limits shared by all attempts of one batched IK solve.

    ``evaluate`` gives the masked pose error ``e = [p_t - p(q); log(R_t R(q)^T)]``
    [m, rad] and its Jacobian; ``project`` and ``inside`` apply the limits.
    """

    robot: Robot
    p_t: Array
    R_t: Array | None
    mask: NDArray[np.bool_]
    lo: Array
    hi: Array
    rev: NDArray[np.bool_]
    limits: bool
    tol_p: float
    tol_o: float

    def __post_init__(self) -> None:
        self.full = bool(self.mask.all())
        self.rows = np.flatnonzero(self.mask)

    def evaluate(self, q: Array, idx: NDArray[np.intp]) -> tuple[Array, Array, Array, Array]:
        """Masked error (M, m), masked Jacobian (M, m, n), |e_p| and |e_o| for targets idx."""
        T, J, _ = self.robot.fk_with_jacobians(q, joints=True, params=False)
        assert J is not None                      # joints=True: the joint Jacobian is made
        dp = self.p_t[idx] - T[:, :3, 3]
        if self.R_t is None:
            w = np.zeros_like(dp)
        else:
            w = log_so3(self.R_t[idx] @ np.swapaxes(T[:, :3, :3], 1, 2))
        if self.full:
            e = np.concatenate([dp, w], 1)
            return (e, J, np.sqrt(np.einsum("ij,ij->i", dp, dp)),
                    np.sqrt(np.einsum("ij,ij->i", w, w)))
        dp, w = dp * self.mask[:3], w * self.mask[3:]
        e = np.concatenate([dp, w], 1)[:, self.rows]
        return (e, J[:, self.rows, :], np.sqrt(np.einsum("ij,ij->i", dp, dp)),
                np.sqrt(np.einsum("ij,ij->i", w, w)))

    def project(self, q: Array) -> Array:
        return project_to_limits(q, self.lo, self.hi, self.rev) if self.limits else q

    def inside(self, q: Array) -> NDArray[np.bool_]:
        if not self.limits:
            return np.ones(q.shape[0], bool)
        inside: NDArray[np.bool_] = np.all((q >= self.lo - 1e-12) & (q <= self.hi + 1e-12),
                                           axis=1)
        return inside
