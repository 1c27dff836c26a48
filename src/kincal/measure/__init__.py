"""Measurements of a robot: models, instruments, artifacts, files and simulation.

A measurement model (:class:`~kincal.measure.base.MeasurementModel`) turns a robot
and its own parameters (instrument frame, marker, sockets) into whitened residuals
and analytic Jacobians; :func:`~kincal.measure.base.stack` joins blocks into one
system for the solver.  The instruments (:mod:`~kincal.measure.instruments`: one
module per instrument - position, pose, range, bearing, camera, plane, fixture -
holding its model, its file columns, its simulator and its registration), the
artifacts - cross-bar, ball-bar, two-socket (:mod:`~kincal.measure.artifacts`) - and
the non-geometric joint terms that wrap any block (:mod:`~kincal.measure.joints`).
CSV files with units (:mod:`~kincal.measure.files`), the instrument registry
(:mod:`~kincal.measure.registry`) and virtual robots (:mod:`~kincal.measure.simulate`).

Layer rule: imports :mod:`kincal.robots`, :mod:`kincal.motion` (artifact simulation
needs IK) and the shared root modules, nothing above.
"""
