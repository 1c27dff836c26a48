"""What one calibration run produced: :class:`FlowResult`.

Its own module so that the flow (:mod:`kincal.workflow.flow`) and the report
sections (:mod:`kincal.workflow.report_sections`) can both use it without importing
each other.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["FlowResult"]


@dataclasses.dataclass
class FlowResult:
    """Everything one calibration run produced.

    Attributes:
        result: the :class:`~kincal.identify.solver.CalibrationResult` (``result.procedure_record``
            for the patent procedure).
        comparisons: errors before/after, ``train`` then ``validation``.
        seconds: wall time of the calibration itself [s].
        warnings: sentences for people (e.g. an instrument that probably moved).
        nominal: the robot the calibration started from.
        train: the training blocks used (the patent's selection keeps only some
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

    result: Any
    comparisons: list[Any]
    seconds: float
    warnings: list[str] = dataclasses.field(default_factory=list)
    nominal: Any = None
    train: list[Any] = dataclasses.field(default_factory=list)
    before: dict[str, Array] = dataclasses.field(default_factory=dict)
    after: dict[str, Array] = dataclasses.field(default_factory=dict)
    cross_validation: dict[str, Any] | None = None
    tolerances: Any = None
    verdict: Any = None
    weak: list[Any] = dataclasses.field(default_factory=list)
    selection: Any = None
    accuracy: Any = None
    heldout: list[Any] = dataclasses.field(default_factory=list)
    notes: list[str] = dataclasses.field(default_factory=list)

    @property
    def trusted(self) -> bool:
        """True unless the verdict says the calibration cannot be trusted."""
        return self.verdict is None or bool(self.verdict.trusted)
