"""Where the numerical IK's attempts start: inside the joint limits, near the target.

* :func:`default_q0` - the first start of every target, mid-range of the limits;
* :func:`random_q` - uniform configurations inside the limits;
* :func:`project_to_limits` - bring configurations inside the limits (revolute joints
  shifted by 2 pi k when that fits, else clipped);
* :class:`SeedPool` - stored random configurations looked up by the nearness of their
  poses to a target: the restarts of :func:`kincal.ik.solve_ik`.

:mod:`kincal.ik` re-exports the functions.  Units: rad, m.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from kincal.robots.chain import Robot

if TYPE_CHECKING:
    from kincal.ik import _Problem

Array = NDArray[np.float64]

__all__ = ["limit_arrays", "default_q0", "random_q", "project_to_limits", "SeedPool"]


def limit_arrays(robot: Robot) -> tuple[Array, Array, NDArray[np.bool_]]:
    """Lower and upper joint limits (n,) [rad / m] and which joints are revolute."""
    lim = robot.joint_limits
    rev = np.array([j.kind == "revolute" for j in robot.joints])
    return lim[:, 0], lim[:, 1], rev


def default_q0(robot: Robot) -> Array:
    """Mid-range of the joint limits; for a half-open range its finite end, or 0 [rad / m]."""
    lo, hi, _ = limit_arrays(robot)
    both = np.isfinite(lo) & np.isfinite(hi)
    mid = np.where(both, 0.5 * (np.where(both, lo, 0) + np.where(both, hi, 0)), 0.0)
    mid = np.where(np.isfinite(lo) & ~np.isfinite(hi), np.maximum(np.nan_to_num(lo), 0.0), mid)
    return np.where(~np.isfinite(lo) & np.isfinite(hi), np.minimum(np.nan_to_num(hi), 0.0), mid)


def random_q(robot: Robot, size: int, rng: np.random.Generator) -> Array:
    """Uniform joint values inside the limits; unlimited sides span pi rad or 1 m."""
    lo, hi, rev = limit_arrays(robot)
    span = np.where(rev, np.pi, 1.0)
    a = np.where(np.isfinite(lo), lo, np.where(np.isfinite(hi), hi - 2 * span, -span))
    b = np.where(np.isfinite(hi), hi, a + 2 * span)
    return rng.uniform(a, b, size=(size, robot.n))


def project_to_limits(q: Array, lo: Array, hi: Array, rev: NDArray[np.bool_]) -> Array:
    """Bring ``q`` inside ``[lo, hi]``: shift revolute joints by 2 pi k if that fits, else clip."""
    outside = (q < lo) | (q > hi)
    if not np.any(outside):
        return q
    with np.errstate(invalid="ignore"):
        shifted = lo + np.mod(q - lo, 2 * np.pi)
    use = outside & rev & (shifted <= hi)
    return np.clip(np.where(use, shifted, q), lo, hi)


class SeedPool:
    """Random configurations inside the limits, looked up by the nearness of their poses.

    Pose distance: ``|dp|^2 / L^2 + |dR|_F^2 / 2`` (about ``|dp / L|^2 + angle^2``),
    restricted to the masked rows; ``L`` is the reach radius.
    """

    def __init__(self, pb: _Problem, size: int, rng: np.random.Generator, scale: float) -> None:
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
