"""Whole calibration runs: files in, a calibrated robot, metrics and a report out.

:mod:`~kincal.workflow.flow` reads the measurement files, runs the calibration (or
the cross-bar procedure), validates on held-out files and writes every output;
:mod:`~kincal.workflow.options` parses the options it shares with the command line,
:mod:`~kincal.workflow.result` holds what a run produced,
:mod:`~kincal.workflow.report_sections` adds the run's own report sections, and
:mod:`~kincal.workflow.robots` loads any kind of robot (serial or five-bar).

Layer rule: imports every layer below (robots to parallel); never the command line.
"""
