"""The defaults module holds the values the workflows used before it existed."""

from __future__ import annotations

import inspect

from kincal import defaults
from kincal.parallel.calibration import calibrate as calibrate_fivebar


def test_default_values_are_unchanged() -> None:
    assert defaults.MAX_ITER == 100 and defaults.STAGE_MAX_ITER == 20
    assert defaults.STAGE_TOLERANCE_M == 1e-7
    assert defaults.FIVEBAR_MAX_ITER == 100 and defaults.FIVEBAR_TOL == 1e-10
    assert defaults.max_iter_for("staged-selection") == 20 and defaults.max_iter_for("lm") == 100


def test_fivebar_calibration_reads_its_defaults_from_the_module() -> None:
    params = inspect.signature(calibrate_fivebar).parameters
    assert params["max_iter"].default == defaults.FIVEBAR_MAX_ITER
    assert params["tol"].default == defaults.FIVEBAR_TOL
