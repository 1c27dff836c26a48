"""The default settings of the calibration workflows, in one place.

Every layer (solver, procedures, workflow, command line) reads its defaults from here so
a default is decided once; this module imports nothing from kincal and sits in the bottom
tier.  Units are SI: lengths in metres.

- ``MAX_ITER = 100``: iterations in all of the Levenberg-Marquardt / Gauss-Newton solver.
- ``STAGE_MAX_ITER = 20``: iterations per stage of the staged-selection procedure.
- ``STAGE_TOLERANCE_M = 1e-7`` [m]: a stage of the staged procedure stops when no
  residual moves by more than this.
- ``FIVEBAR_MAX_ITER = 100`` and ``FIVEBAR_TOL = 1e-10``: the five-bar iteration stops
  when the largest parameter step is below ``FIVEBAR_TOL`` (its units: m, rad).
"""

from __future__ import annotations

MAX_ITER: int = 100
STAGE_MAX_ITER: int = 20
STAGE_TOLERANCE_M: float = 1e-7
FIVEBAR_MAX_ITER: int = 100
FIVEBAR_TOL: float = 1e-10


def max_iter_for(procedure: str) -> int:
    """The default iteration budget of ``procedure``: per stage for ``"staged-selection"``, in all
    otherwise."""
    return STAGE_MAX_ITER if procedure == "staged-selection" else MAX_ITER
