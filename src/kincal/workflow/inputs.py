"""The inputs of one calibration run as people read them: the report's "Inputs" table and
the result JSON's ``inputs`` (:func:`kincal.workflow.flow.write_outputs` takes it).

:func:`calibration_inputs` says, for each choice of :func:`~kincal.workflow.flow.run_flow`,
what was used, with the defaults spelled out (the automatic parameter set, the default
tolerances as priors, the geometric-only joint model); the staged-selection procedure
adds its own stages, data selection, cycles and stop tolerance (shown in mm).
"""

from __future__ import annotations

from collections.abc import Sequence

from kincal.defaults import STAGE_TOLERANCE_M
from kincal.identify.tolerances import describe_defaults

__all__ = ["calibration_inputs"]


def calibration_inputs(*, robot: str, data: Sequence[str], validation: Sequence[str] = (),
                       procedure: str = "lm", staged: bool = False, method: str = "lm",
                       loss: str = "linear", stages: str | None = None,
                       validation_frames: str = "auto", free: str | None = None,
                       fix: str | None = None, prior: str | None = None,
                       terms: Sequence[str] = (), folds: int | None = None,
                       condition_growth: float | None = None, cycles: int | None = None,
                       tolerance: float | None = None) -> dict[str, str]:
    """``{label: text}`` of a calibration run's inputs.

    Args:
        robot: the robot as given (name or file).
        data, validation: the training and held-out files.
        procedure: the procedure's name as the user gave it (``--procedure``).
        staged: the procedure is the two-stage staged selection (angles, then lengths).
        method, loss, stages, validation_frames, free, fix, prior: the options as given.
        terms: the joint model's terms (empty: geometric only).
        folds: K of the model selection by K-fold cross-validation (None: no selection).
        condition_growth, cycles, tolerance: the staged selection's options (tolerance
            in m; None: its defaults).
    """
    inputs = {"robot": robot, "data": ", ".join(data),
              "validation": ", ".join(validation) or "-",
              "procedure": procedure, "method": method, "loss": loss,
              "stages": stages or "all", "validation frames": validation_frames,
              "free": free or "automatic (identifiable set)", "fixed": fix or "-",
              "prior": prior or f"default tolerances ({describe_defaults()})",
              "joint model": ", ".join(terms) or "geometric only",
              "model selection": (f"--select auto, {folds}-fold cross-validation on the "
                                  "training files" if folds is not None else "none")}
    if staged:
        inputs.update({"method": "staged selection (two stages: angles, then lengths)",
                       "stages": "angles, lengths",
                       "condition growth": "-" if condition_growth is None
                       else f"{condition_growth:g}",
                       "cycles": "until converged" if cycles is None else str(cycles),
                       "tolerance": f"{(tolerance or STAGE_TOLERANCE_M) * 1e3:g} mm"})
    return inputs
