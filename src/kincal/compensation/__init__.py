"""Putting a calibration to use: joint commands and filtered targets for the robot.

:mod:`~kincal.compensation.compensate` solves, for every target, the joint commands
that put the calibrated (real) robot on it, and the filtered target to send to a
controller that only knows the nominal model.

Layer rule: imports :mod:`kincal.identify` and everything below it; never the
report, the workflow or the command line.
"""
