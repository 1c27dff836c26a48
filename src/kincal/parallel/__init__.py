"""The five-bar (dual SCARA) parallel robot: a closed chain with its own calibration.

:mod:`~kincal.parallel.fivebar` is the robot as an immutable value (forward
kinematics with assembly modes, inverse kinematics with working modes),
:mod:`~kincal.parallel.kinematics` its formulas, :mod:`~kincal.parallel.mobility`
the Gruebler-Kutzbach count, :mod:`~kincal.parallel.workspace` the reachable region,
:mod:`~kincal.parallel.files` and :mod:`~kincal.parallel.data` its robot and
measurement files, and :mod:`~kincal.parallel.calibration` (with
:mod:`~kincal.parallel.residuals`, :mod:`~kincal.parallel.identifiability`) the
inverse-kinematics-residual calibration; :mod:`~kincal.parallel.reference_experiment` reproduces
the reference study.

Layer rule: imports :mod:`kincal.report`, :mod:`kincal.identify` and everything below
them; never the workflow or the command line.
"""
