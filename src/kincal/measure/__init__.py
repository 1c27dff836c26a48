"""Measurements of a robot: models, instruments, artifacts, files and simulation.

A measurement model (:class:`~kincal.measure.base.MeasurementModel`) turns a robot
and its own parameters (instrument frame, marker, sockets) into whitened residuals
and analytic Jacobians; :func:`~kincal.measure.base.stack` joins blocks into one
system for the solver.  Position and pose (:mod:`~kincal.measure.models`), the other
instruments (:mod:`~kincal.measure.instruments`), the artifacts - cross-bar,
ball-bar, two-socket (:mod:`~kincal.measure.artifacts`) - and the non-geometric
joint terms that wrap any block (:mod:`~kincal.measure.joints`).  CSV files with
units (:mod:`~kincal.measure.files`, :mod:`~kincal.measure.registry`) and simulated
experiments (:mod:`~kincal.measure.simulate`).

Layer rule: imports :mod:`kincal.robots`, :mod:`kincal.motion` (artifact simulation
needs IK) and the shared root modules, nothing above.
"""
