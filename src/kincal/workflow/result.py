"""What one calibration run produced: :class:`FlowResult`.

Its own module so that the flow (:mod:`kincal.workflow.flow`) and the report
sections (:mod:`kincal.workflow.report_sections`) can both use it without importing
each other.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:                  # types only: no import cost, no circle
    from kincal.identify.accuracy import AccuracyModel
    from kincal.identify.checks import Verdict
    from kincal.identify.selection import Selection
    from kincal.identify.solver import CalibrationResult
    from kincal.identify.tolerances import Tolerances
    from kincal.identify.weak import WeakParameter
    from kincal.measure.base import MeasurementModel
    from kincal.report.metrics import ErrorComparison
    from kincal.robots.chain import Robot
    from kincal.workflow.heldout import HeldOutFile

Array = NDArray[np.float64]

__all__ = ["FlowResult"]


@dataclasses.dataclass
class FlowResult:
    """Everything one calibration run produced.

    Attributes:
        result: the :class:`~kincal.identify.solver.CalibrationResult` (``result.procedure_record``
            for the staged-selection procedure).
        comparisons: errors before/after, ``train`` then ``validation``.
        seconds: wall time of the calibration itself [s].
        warnings: sentences for people (e.g. an instrument that probably moved).
        nominal: the robot the calibration started from.
        train: the training blocks used (the procedure's selection keeps only some
            placements); ``before`` / ``after``: their block parameters fitted to the
            nominal robot / estimated with the calibrated one, by block name.
        cross_validation: with ``run_flow(cross_validate=K)``: ``{"folds": K, "seed":
            0, "split": "rows" | "placements", "rms_<kind>": pooled held-out RMS}``.
        tolerances: the parameters' manufacturing tolerances
            (:class:`~kincal.identify.tolerances.Tolerances`): the prior and the
            plausibility bounds.
        verdict: whether the calibration can be trusted
            (:class:`~kincal.identify.checks.Verdict`: converged, every estimate within
            10 tolerances of nominal).
        weak: the parameters the prior holds and what would identify them
            (:class:`~kincal.identify.weak.WeakParameter`).
        selection: with ``select="auto"``, the cross-validation of every candidate model
            and the choice (:class:`~kincal.identify.selection.Selection`).
        accuracy: the calibration's predicted accuracy
            (:class:`~kincal.identify.accuracy.AccuracyModel`).
        heldout: one :class:`~kincal.workflow.heldout.HeldOutFile` per held-out block.
        notes: sentences on what the run did (e.g. a shared tool point).
    """

    result: CalibrationResult
    comparisons: list[ErrorComparison]
    seconds: float
    warnings: list[str] = dataclasses.field(default_factory=list)
    nominal: Robot | None = None
    train: list[MeasurementModel] = dataclasses.field(default_factory=list)
    before: dict[str, Array] = dataclasses.field(default_factory=dict)
    after: dict[str, Array] = dataclasses.field(default_factory=dict)
    cross_validation: dict[str, Any] | None = None
    tolerances: Tolerances | None = None
    verdict: Verdict | None = None
    weak: list[WeakParameter] = dataclasses.field(default_factory=list)
    selection: Selection | None = None
    accuracy: AccuracyModel | None = None
    heldout: list[HeldOutFile] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)

    @property
    def trusted(self) -> bool:
        """True unless the verdict says the calibration cannot be trusted."""
        return self.verdict is None or bool(self.verdict.trusted)
