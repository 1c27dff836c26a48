"""The ISO 9283 test plan of a robot: its test cube, the five positions and the cycles.

:func:`plan_iso9283_cube` places the test cube (:func:`kincal.identify.iso9283.
cube_positions`) about a well-conditioned centre posture and solves the inverse kinematics
of ``P1 ... P5`` with the tool orientation of that posture:

* centre posture: of 2000 random configurations inside the joint limits (20 % - 80 % of
  each range, seed 0; an infinite limit counts as +-pi), the 20 % with the smallest
  Jacobian condition number, and among them the one whose tool point is nearest their
  median;
* edge ``L`` (default a quarter of the reach bound, :func:`kincal.motion.ik.reach_bound`)
  halved, at most five times, until every position is reachable;
* the joint rows: ``cycles`` repetitions of the cycle ``P1 P5 P4 P3 P2``.

:class:`Iso9283Plan` holds the result (SI units) with its :meth:`~Iso9283Plan.to_dict`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError
from kincal.identify.iso9283 import CYCLE, cube_positions
from kincal.robots.chain import Robot

__all__ = ["Iso9283Plan", "plan_iso9283_cube"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Iso9283Plan:
    """An ISO 9283 test plan.

    Attributes:
        robot: the robot's name.
        size: cube edge L [m]; ``center``: cube centre (3,) [m] in the base frame.
        positions: ``{"P1": (3,), ...}`` commanded positions [m].
        joints: ``{"P1": (n,), ...}`` joint values reaching them [rad / m].
        cycles: repetitions of :data:`~kincal.identify.iso9283.CYCLE`.
    """

    robot: str
    size: float
    center: Array
    positions: dict[str, Array]
    joints: dict[str, Array]
    cycles: int

    @property
    def names(self) -> list[str]:
        """The positions, P1 ... P5."""
        return list(self.positions)

    @property
    def rows(self) -> Array:
        """The joint rows to run: ``cycles`` x (P1 P5 P4 P3 P2), (5 cycles, n)."""
        return np.array([self.joints[n] for _ in range(self.cycles) for n in CYCLE])

    def comments(self) -> list[str]:
        """Header lines of the pose file: the cube and each position [mm]."""
        out = [f"kincal plan --iso9283: robot={self.robot}; cube edge {self.size * 1e3:.1f} "
               f"mm, centre {', '.join(f'{v * 1e3:.1f}' for v in self.center)} mm; "
               f"{self.cycles} cycles of {' '.join(CYCLE)} (rows in that order)"]
        return out + [f"{n}: {', '.join(f'{v * 1e3:.3f}' for v in p)} mm"
                      for n, p in self.positions.items()]

    def to_dict(self, output: str | None = None) -> dict[str, Any]:
        """Plain mapping for JSON (SI); ``output``: the file the rows went to."""
        return {"robot": self.robot, "cube_edge_m": self.size,
                "center_m": self.center.tolist(),
                "positions_m": {n: p.tolist() for n, p in self.positions.items()},
                "joints": {n: q.tolist() for n, q in self.joints.items()},
                "cycle": list(CYCLE), "cycles": self.cycles, "output": output}


def _centre_posture(robot: Robot) -> Array:
    """A well-conditioned posture central among such (module docstring)."""
    from kincal.motion.joint_limits import default_q0

    rng = np.random.default_rng(0)
    lo, hi = robot.joint_limits[:, 0], robot.joint_limits[:, 1]
    lo, hi = np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)
    cand = lo + (hi - lo) * rng.uniform(0.2, 0.8, (2000, robot.n))
    cond = np.linalg.cond(robot.jacobian(cand))
    good = cand[cond < np.percentile(cond, 20)]
    if not len(good):
        return default_q0(robot)
    pos = robot.fk(good)[:, :3, 3]
    return np.asarray(good[np.argmin(np.linalg.norm(pos - np.median(pos, axis=0), axis=1))],
                      dtype=float)


def plan_iso9283_cube(robot: Robot, center: Sequence[float] | None = None,
                      size: float | None = None, cycles: int = 30) -> Iso9283Plan:
    """The ISO 9283 test plan of ``robot`` (module docstring).

    Args:
        robot: the robot.
        center: cube centre [m] (default: the tool point of the centre posture).
        size: cube edge [m] (default: a quarter of the reach, halved until reachable).
        cycles: repetitions of the cycle (the standard: 30).

    Raises:
        KincalError: a position is not reachable with the centre's tool orientation.
    """
    from kincal.motion.ik import reach_bound, solve_ik

    q0 = _centre_posture(robot)
    T0 = robot.fk(q0)
    c = np.asarray(center, dtype=float) if center is not None else np.asarray(T0[:3, 3])
    edge = float(size) if size is not None else 0.25 * reach_bound(robot)[1]
    for _ in range(1 if size is not None else 6):  # default size: halve until every one fits
        P = cube_positions(c, edge)
        names = list(P)
        T = np.tile(T0, (5, 1, 1))
        T[:, :3, 3] = [P[n] for n in names]
        sol = solve_ik(robot, T, q0=q0)
        if sol.success.all():
            break
        edge /= 2
    bad = [n for n, ok in zip(names, sol.success, strict=True) if not ok]
    if bad:
        k = names.index(bad[0])
        raise KincalError(f"ISO 9283 position {bad[0]} at {np.round(P[bad[0]] * 1e3, 1).tolist()} "
                          f"mm is not reachable with the tool orientation at the centre "
                          f"({sol.reason[k]}); give a smaller --cube-size or another "
                          "--cube-center")
    joints = {n: np.asarray(q, dtype=float) for n, q in zip(names, sol.q, strict=True)}
    return Iso9283Plan(robot.name, edge, c, {n: P[n] for n in names}, joints, cycles)
