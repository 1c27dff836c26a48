"""One stage of the solver: iterate a method from a starting point until a stopping rule.

:func:`run_stage` linearises the weighted problem at the current point
(:class:`~kincal.identify.linearisation.Linearisation`: the QR triangle
``[W^1/2 J | W^1/2 r] = Q [[R, z], [0, rho]]``, reused where safe), scales it by the
column norms (``A = R D^-1``, ``D`` the largest column norms seen in the stage), asks the
method for a step (:func:`~kincal.identify.gauss_newton.gauss_newton_step`,
:func:`~kincal.identify.levenberg_marquardt.levenberg_marquardt_step`), takes it, and asks
the stopping rules (:mod:`~kincal.identify.stopping`) in turn; the first that holds ends
the stage with its :class:`~kincal.identify.status.StageStatus`:

* before a step: the cost is not finite; the remaining Gauss-Newton step is within
  ``tol_std`` standard errors (``|z| <= tol_std s0``, loss ``"linear"`` only);
* from the method: it found no acceptable point (its ``Step.stop``);
* after a step: the step is within ``tol_step``; the cost changed by less than
  ``tol_cost`` (absolute for Gauss-Newton; relative, and the robust weights settled, for
  Levenberg-Marquardt); the residuals are zero; ``max_iter`` iterations.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from kincal.identify.gauss_newton import gauss_newton_step
from kincal.identify.levenberg_marquardt import Damping, levenberg_marquardt_step
from kincal.identify.linearisation import Linearisation, LinearisedProblem
from kincal.identify.prior import WithPrior
from kincal.identify.robust import RobustLoss
from kincal.identify.status import StageStatus, stage_message
from kincal.identify.steps import Step
from kincal.identify.stopping import (
    cost_change_below,
    step_below,
    step_within_standard_errors,
)
from kincal.measure.base import CompressedSystem

Array = NDArray[np.float64]


@dataclass
class IterationRecord:
    """One iteration of the solver.

    Attributes:
        stage: the stage's label (``"all"``, ``"offsets"`` ...).
        iteration: 0 for the starting point of the stage, then 1, 2 ...
        theta: the full parameter vector after the iteration (over ``problem.names``).
        cost: ``1/2 sum w r^2`` (whitened, robust-weighted).
        rms: RMS of the whitened residuals (dimensionless; ~1 at the noise floor).
        step: largest scaled step ``|dx_j| / (1 + |x_j|)`` of the iteration.
        damping: Levenberg-Marquardt ``lambda`` (0 for Gauss-Newton).
    """

    stage: str
    iteration: int
    theta: Array
    cost: float
    rms: float
    step: float = 0.0
    damping: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {"stage": self.stage, "iteration": self.iteration, "cost": float(self.cost),
                "rms": float(self.rms), "step": float(self.step),
                "damping": float(self.damping)}


@dataclass(frozen=True)
class StageSettings:
    """How every stage of a calibration iterates (see :func:`~kincal.identify.solver.calibrate`).

    Attributes:
        method: ``"lm"`` or ``"gauss-newton"``.
        loss: the robust loss and what its weights need.
        max_iter: iterations per stage.
        tol_step: step rule ``|dx_j| <= tol_step (1 + |x_j|)`` [m / rad].
        tol_cost: cost-change rule (relative for Levenberg-Marquardt).
        tol_std: standard-error rule (0: off).
        progress: called with every :class:`IterationRecord`.
    """

    method: str
    loss: RobustLoss
    max_iter: int
    tol_step: float
    tol_cost: float
    tol_std: float
    progress: Callable[[IterationRecord], Any] | None = None


class StageEnd(NamedTuple):
    """What :func:`run_stage` ends with; ``r`` (prior rows included) at ``theta``."""

    theta: Array
    status: StageStatus
    iterations: int
    message: str
    r: Array
    #: the triangle at ``theta`` over the stage's columns, when the stage has it (prior
    #: rows included, as the stage used it; without ``r``); None otherwise
    C: CompressedSystem | None = None
    #: the same without the prior rows (the measurements' own), when the stage has it
    data: CompressedSystem | None = None
    #: ``C`` and ``data`` were built at ``theta``; False when the stage ended on a step
    #: shorter than tol_step, whose triangle was not built: they are those where that
    #: step started (``R`` stands for the one at ``theta``; ``z``, ``rho``, ``cost`` do not)
    exact: bool = True

    @property
    def converged(self) -> bool:
        """Whether the stage ended at a minimum (derived from ``status``)."""
        return self.status.converged


class _Stage:
    """The bookkeeping of one stage: its label, settings, history and how it ends."""

    def __init__(self, prob: LinearisedProblem, lin: Linearisation, label: str,
                 settings: StageSettings, history: list[IterationRecord]) -> None:
        self.prob, self.lin, self.label = prob, lin, label
        self.settings, self.history = settings, history

    def record(self, it: int, w: Array, step: float, lam: float) -> None:
        """Append the iteration's record at the current point (and report it)."""
        lin = self.lin
        cost = lin.cost(w)
        rec = IterationRecord(self.label, it, lin.theta.copy(), cost, lin.rms(w), step, lam)
        self.history.append(rec)
        if self.settings.progress is not None:
            self.settings.progress(rec)

    def end(self, status: StageStatus, iterations: int) -> StageEnd:
        """The stage's outcome at the current point."""
        lin, s = self.lin, self.settings
        prob = self.prob
        data = (prob.measurements_at(lin.triangle_theta)
                if isinstance(prob, WithPrior) and prob.rows else lin.triangle)
        message = stage_message(status, self.label, tol_std=s.tol_std, max_iter=s.max_iter)
        return StageEnd(lin.theta, status, iterations, message, lin.residuals(),
                        lin.triangle, data, lin.exact)


def _after_step(method: str, step: Step, cost: float, w: Array, w_old: Array,
                tol_step: float, tol_cost: float) -> StageStatus | None:
    """The stopping rules asked after a step is taken, in turn."""
    if step_below(step.length, tol_step):
        return StageStatus.STEP_BELOW_TOL
    if method == "gauss-newton":
        return (StageStatus.COST_CHANGE_BELOW_TOL if cost_change_below(cost, step.cost, tol_cost)
                else None)
    if (cost_change_below(cost, step.cost, tol_cost, absolute=False)
            and np.allclose(w, w_old, atol=1e-6)):
        return StageStatus.COST_CHANGE_BELOW_TOL
    if step.cost == 0.0:
        return StageStatus.ZERO_RESIDUAL
    return None


def run_stage(prob: LinearisedProblem, theta: Array, est: list[int], label: str,
              settings: StageSettings, history: list[IterationRecord], n_fixed: int = 0,
              start: CompressedSystem | None = None) -> StageEnd:
    """Iterate one stage to convergence from ``theta`` over the columns ``est``.

    ``prob`` is a :class:`~kincal.measure.base.StackedProblem` or a
    :class:`~kincal.identify.prior.WithPrior` whose ``n_fixed`` trailing prior rows keep
    weight 1.  Each linearisation is the QR triangle of the weighted problem over ``est``
    (``start``: the one at ``theta`` with its residuals, if the caller has it), never the
    (M, P) Jacobian.  Returns the final ``theta``, the status that ended the stage, the
    iterations, its message, and ``r`` (prior rows included) at that ``theta``.
    """
    s = settings
    loss = s.loss
    lin = Linearisation(prob, theta, start, reuse_trials=loss.linear)
    start = None                            # no reference to a residual vector is kept
    w = (loss.uniform(prob.num_residuals()) if loss.linear
         else loss.weights(lin.residuals(), n_fixed))
    stage = _Stage(prob, lin, label, s, history)
    stage.record(0, w, 0.0, 0.0)
    if not est:
        return stage.end(StageStatus.NOTHING_TO_ESTIMATE, 0)
    damping = Damping()
    Dmax = np.zeros(len(est))
    dof = prob.num_residuals() - len(est)
    for it in range(1, s.max_iter + 1):
        here = lin.linearise(w, est)
        # [W^1/2 J | W^1/2 r] = Q [[R, z], [0, rho]]: R D^-1 = U S V^T, g = U^T z
        Dmax = np.maximum(Dmax, np.linalg.norm(here.R, axis=0))
        Ds = np.where(Dmax > 0, Dmax, 1.0)
        A = here.R / Ds
        cost = lin.cost(w)
        if not np.isfinite(cost):
            return stage.end(StageStatus.NON_FINITE_RESIDUALS, it - 1)
        # the full Gauss-Newton step moves |R dx| = |z| (at most): within tol_std
        # standard errors the stage is at its minimum (s0^2 = 2 cost / dof, or 1 if
        # smaller: never looser than the stated sigmas' standard errors)
        if (loss.linear and lin.exact
                and step_within_standard_errors(float(here.z @ here.z), cost, dof, s.tol_std)):
            return stage.end(StageStatus.WITHIN_STANDARD_ERRORS, it - 1)
        lin.drop_residuals()
        if s.method == "gauss-newton":
            step = gauss_newton_step(lin, A, Ds, here.z, est, w, s.tol_step)
            if step.stop is not None:           # the step was not taken
                return stage.end(step.stop, it - 1)
        else:
            step = levenberg_marquardt_step(lin, damping, A, Ds, here.z, est, w, cost,
                                            s.tol_step)
            if step.stop is StageStatus.DAMPING_FAILED:
                return stage.end(step.stop, it)
            if step.stop is not None:
                stage.record(it, w, 0.0, step.damping)
                return stage.end(step.stop, it)
        lin.move(step.theta, step.r, step.triangle, step.tiny)
        w_old, w = w, loss.weights(step.r, n_fixed)
        stage.record(it, w, step.length, step.damping)
        status = _after_step(s.method, step, cost, w, w_old, s.tol_step, s.tol_cost)
        if status is not None:
            return stage.end(status, it)
    return stage.end(StageStatus.MAX_ITER_REACHED, s.max_iter)
