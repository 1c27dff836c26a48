"""Why one stage of the least-squares solver stopped: an integer status and its message.

As scipy's ``OptimizeResult.status``, a program reads :class:`StageStatus` (an
:class:`~enum.IntEnum`) instead of parsing English; :func:`stage_message` renders the
status into the sentence shown to a person, from the single table :data:`MESSAGES`.
Positive values are stops at a minimum (the stage converged), negative values are
failures, as in scipy's convention.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["MESSAGES", "StageStatus", "stage_message"]


class StageStatus(IntEnum):
    """The rule that ended a stage; ``> 0``: converged, ``< 0``: not converged."""

    NOTHING_TO_ESTIMATE = 1
    WITHIN_STANDARD_ERRORS = 2
    STEP_BELOW_TOL = 3
    COST_CHANGE_BELOW_TOL = 4
    NO_FURTHER_DECREASE = 5
    NO_DESCENT_STEP = 6
    ZERO_RESIDUAL = 7
    NON_FINITE_RESIDUALS = -1
    GAUSS_NEWTON_DIVERGED = -2
    DAMPING_FAILED = -3
    MAX_ITER_REACHED = -4

    @property
    def converged(self) -> bool:
        """Whether the stage ended at a minimum."""
        return self.value > 0


#: the sentence for each status; ``{tol_std}`` and ``{max_iter}`` are filled in
MESSAGES: dict[StageStatus, str] = {
    StageStatus.NOTHING_TO_ESTIMATE: "nothing to estimate",
    StageStatus.WITHIN_STANDARD_ERRORS: ("the remaining step is below tol_std = {tol_std:g} "
                                         "standard errors"),
    StageStatus.STEP_BELOW_TOL: "step below tol_step",
    StageStatus.COST_CHANGE_BELOW_TOL: "cost change below tol_cost",
    StageStatus.NO_FURTHER_DECREASE: ("no further decrease possible "
                                      "(at a minimum to machine precision)"),
    StageStatus.NO_DESCENT_STEP: "no descent step longer than tol_step (at a minimum)",
    StageStatus.ZERO_RESIDUAL: "zero residual",
    StageStatus.NON_FINITE_RESIDUALS: "the residuals are not finite",
    StageStatus.GAUSS_NEWTON_DIVERGED: ("Gauss-Newton diverged (non-finite residuals); "
                                        "try method='lm'"),
    StageStatus.DAMPING_FAILED: "the damping did not find a descent step",
    StageStatus.MAX_ITER_REACHED: "max_iter={max_iter} reached",
}


def stage_message(status: StageStatus, label: str, tol_std: float = 0.0,
                  max_iter: int = 0) -> str:
    """The sentence ``stage 'label': <MESSAGES[status]>`` with the tolerances filled in."""
    return f"stage {label!r}: " + MESSAGES[status].format(tol_std=tol_std, max_iter=max_iter)
