"""Joint hysteresis: each joint lags by a constant amount behind its last motion.

Backlash between a motor-side encoder and the link (gear play, a loose coupling), with
friction holding the link where it stopped, leaves the link at

    q_eff = q + h (.) d

where ``d_j`` in {-1, 0, +1} is the direction joint ``j`` moved in to reach the
posture and ``h_j`` [rad / m] the hysteresis: half the play, negative when the link
lags behind the motor (the usual case: ``h = -b/2`` for a play ``b``).  The
directions come from the order the postures were measured in
(:func:`approach_directions`): a posture approached from below sits ``2|h|`` away
from the same posture approached from above, a difference no geometric parameter can
produce.

:class:`JointHysteresis` is the :class:`~kincal.measure.joints.deflection.JointDeflection`
with regressor ``u = d`` and parameters ``{name}.h[<joint>]``; it nests with
:class:`~kincal.measure.joints.compliance.JointCompliance` (gravity-loaded play shows as
compliance, friction-held play as hysteresis).  The model needs the measurement rows
in the order they were taken, with the robot moving from each posture straight to the
next: build it on a whole session, then take subsets (cross-validation folds keep
each row's direction).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError
from kincal.measure.base import MeasurementModel
from kincal.measure.joints.deflection import JointDeflection
from kincal.robots.chain import Robot

Array = NDArray[np.float64]

__all__ = ["JointHysteresis", "approach_directions", "MIN_MOVE"]

#: Smallest joint motion [rad or m] between consecutive postures that counts as a move;
#: a smaller change is read as the joint standing still (its play stays where it was).
#: 1 mrad / 1 mm is above the jitter of averaged static encoder readings.
MIN_MOVE = 1e-3


def approach_directions(q: ArrayLike, min_move: float = MIN_MOVE) -> Array:
    """Direction each joint moved in to reach each posture, from the posture sequence.

    ``d[k, j] = sign(q[k, j] - q[k-1, j])`` when the joint moved by more than
    ``min_move``; otherwise the joint stood still and keeps ``d[k-1, j]``.  The first
    posture's direction is unknown: 0 (the middle of the play) until the joint's first
    move.

    Args:
        q: (N, n) joint readings [rad / m] in the order they were measured.
        min_move: smallest change that counts as a move [rad / m].

    Returns:
        (N, n) array of -1.0, 0.0 or +1.0.
    """
    q = np.asarray(q, dtype=float)
    if q.ndim != 2:
        raise KincalError(f"approach directions need (N, n) joint readings, got shape {q.shape}")
    if not np.all(np.isfinite(q)):
        raise KincalError("approach directions: the joint readings are not all finite")
    if not (np.isfinite(min_move) and min_move >= 0):
        raise KincalError(f"approach directions: min_move must be >= 0, got {min_move}")
    d = np.zeros_like(q)
    if q.shape[0] < 2:
        return d
    step = np.diff(q, axis=0)
    moved = np.abs(step) > min_move
    # a move sets the direction; standing still carries the last one forward: index of
    # the latest move at or before each row (vectorised forward fill)
    signs = np.where(moved, np.sign(step), 0.0)
    rows = np.arange(1, q.shape[0])[:, None]
    last = np.maximum.accumulate(np.where(moved, rows, 0), axis=0)
    filled = np.where(last > 0, signs[np.maximum(last - 1, 0), np.arange(q.shape[1])], 0.0)
    d[1:] = filled
    return d


class JointHysteresis(JointDeflection):
    """Evaluate ``block`` at ``q + h (.) d`` and estimate the joint hysteresis ``h``.

    Args:
        block: the inner measurement block (its ``q`` are the encoder readings, its rows
            in the order they were measured unless ``directions`` is given).
        robot: the robot the block measures.
        directions: (N, n) approach directions in {-1, 0, +1}; default
            :func:`approach_directions` of ``block.q`` with ``min_move``.
        joints: names of the joints that get a hysteresis (default: all).
        min_move: see :func:`approach_directions` [rad / m].

    Parameters: the inner block's, then ``{name}.h[<joint>]`` per joint in ``joints``
    [rad or m], role ``"hysteresis"``, initial value 0.
    """

    SYMBOL = "h"
    ROLE = "hysteresis"
    WHAT = "joint hysteresis"
    REGRESSOR = "directions"

    def __init__(self, block: MeasurementModel, robot: Robot,
                 directions: ArrayLike | None = None, joints: Sequence[str] | None = None,
                 min_move: float = MIN_MOVE) -> None:
        if directions is None:
            directions = approach_directions(block.q, min_move)
        d = np.asarray(directions, dtype=float)
        if d.shape == np.shape(block.q) and not np.all(np.isin(d, (-1.0, 0.0, 1.0))):
            raise KincalError(f"joint hysteresis of {block.name!r}: directions must be "
                              "-1, 0 or +1")
        super().__init__(block, robot, d, joints)

    @property
    def directions(self) -> Array:
        """(N, n) approach directions the hysteresis multiplies."""
        return self.regressor
