"""Where the numerical IK's restarts start: stored configurations near the target.

:class:`SeedPool` keeps random configurations inside the joint limits and looks them
up by the nearness of their poses to a target: the restarts of
:func:`kincal.motion.ik.solve_ik`.  Units: rad, m.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kincal.motion.ik_problem import IKProblem
from kincal.motion.joint_limits import project_to_limits, random_q

Array = NDArray[np.float64]

__all__ = ["SeedPool"]


class SeedPool:
    """Random configurations inside the limits, looked up by the nearness of their poses.

    Pose distance: ``|dp|^2 / L^2 + |dR|_F^2 / 2`` (about ``|dp / L|^2 + angle^2``),
    restricted to the masked rows; ``L`` is the reach radius.
    """

    def __init__(self, pb: IKProblem, size: int, rng: np.random.Generator, scale: float) -> None:
        self.q = random_q(pb.robot, size, rng)
        if pb.limits:
            self.q = project_to_limits(self.q, pb.lo, pb.hi, pb.rev)
        T = pb.robot.fk(self.q)
        self.pb, self.scale = pb, scale
        self.features = self._features(T[:, :3, 3], T[:, :3, :3]).astype(np.float32)
        self.norms = np.einsum("ij,ij->i", self.features, self.features)
        self.features_t = np.ascontiguousarray(self.features.T)

    def _features(self, p: Array, R: Array | None) -> Array:
        parts = [p[:, self.pb.mask[:3]] / self.scale]
        if R is not None and self.pb.mask[3:].any():
            parts.append(R.reshape(-1, 9) / np.sqrt(2.0))
        return np.concatenate(parts, 1)

    def nearest(self, idx: NDArray[np.intp], first: int, count: int) -> NDArray[np.intp]:
        """Pool rows of nearness ranks ``first .. first + count - 1`` for targets idx."""
        R = self.pb.R_t[idx] if self.pb.R_t is not None else None
        F = self._features(self.pb.p_t[idx], R).astype(np.float32)
        last = min(first + count, self.q.shape[0])
        out = np.empty((idx.size, last - first), np.intp)
        step = 128                                  # rows per block: stays in cache
        for s in range(0, idx.size, step):
            # |f|^2 - 2 f.g + |g|^2 less the constant |f|^2; einsum, not BLAS, whose
            # threads spin and cost more than they give on blocks this small
            d2 = np.einsum("ij,jk->ik", F[s:s + step], self.features_t)
            d2 *= -2.0
            d2 += self.norms
            if last == 1:
                out[s:s + step, 0] = np.argmin(d2, axis=1)
                continue
            part = np.argpartition(d2, last - 1, axis=1)[:, :last]
            order = np.argsort(np.take_along_axis(d2, part, 1), axis=1)
            out[s:s + step] = np.take_along_axis(part, order, 1)[:, first:last]
        return out
