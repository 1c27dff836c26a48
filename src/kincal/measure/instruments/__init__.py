"""The instruments: one module each, holding its model, its file columns and its simulator.

Each instrument module holds a :class:`~kincal.measure.base.MeasurementModel` (whitened
residuals, analytic Jacobians for every robot parameter and for its own parameters,
closed-form initial guess), the writer and reader of its CSV columns, its simulator, and
the :func:`~kincal.measure.registry.register` call of its
:class:`~kincal.measure.registry.InstrumentPlugin`; importing the module registers it for
``kincal simulate --instrument NAME`` and ``kincal calibrate --data file.csv``
(:data:`kincal.measure.registry.INSTRUMENT_MODULES` lists them).  Shared pieces:
:mod:`.common` (frame and marker parameters, rotations, shared checks), :mod:`.pointblock`
(the base class of the point instruments), :mod:`.csvio` (instrument CSV tables) and
:mod:`.placement` (the simulators' workspace placement and contact solver).

========  ==========================================  =====================================
name      model (module)                              block parameters
========  ==========================================  =====================================
position  :class:`PositionMeasurement` (``position``) ``{name}.x/.../rx``,
                                                      ``{name}.marker[k].x/y/z``
pose      :class:`PoseMeasurement` (``pose``)         ``{name}.x/.../rx``,
                                                      ``{name}.target.x/.../rx``
range     :class:`RangeMeasurement` (``range``)       ``{name}.{station}.x/y/z``,
                                                      ``{name}.{station}.L0[.{run}]``
bearing   :class:`BearingMeasurement` (``bearing``)   ``{name}.{station}.x/y/z/rz/ry/rx``
camera    :class:`CameraMeasurement`,                 ``{name}.{camera}.x/.../rx`` (fixed),
          :class:`HandCameraMeasurement` (``camera``) ``{name}.target.x/.../rx`` (hand)
plane     :class:`PlaneMeasurement` (``plane``)       ``{name}.{plane}.rx/ry/d`` (unknown)
fixture   :class:`FixtureMeasurement` (``fixture``)   none
========  ==========================================  =====================================

The tool point.  Point instruments see a marker ``p = p_e + R_e m`` on the tool.  By
default (``marker=own``) ``m`` is the block's ``{name}.marker.x/y/z``, like
``PositionMeasurement``.  To fuse instruments that see the *same* physical marker,
give every such block ``marker=tool``: the point is then the robot's tool origin, and
the robot's ``tool.x/y/z`` -- shared by all blocks -- play the marker (set the robot's
tool frame to the nominal marker offset).  Two blocks with ``marker=own`` each estimate
their own marker: correct for different markers, weaker for one.

Fusion is stacking: ``calibrate(robot, [range_block, bearing_block, ...])`` weighs every
residual by its own block's sigma, estimates all stations with the robot, and the
identifiability report covers the whole set.

What each instrument cannot see (reported by name by the identifiability analysis):

* every instrument with an unknown frame: the robot's base frame (the station/camera
  poses take its place) and joint 1's offset about the base z axis;
* range: the three rotations of the set-up about a single station (with surveyed
  station positions, one station still leaves the base orientation free);
* bearing and fixed cameras: the scale (angles and images do not change when the scene
  is scaled about the instrument): one length is dependent; fuse a range or fix a length;
* plane: motion within each plane; with unknown planes the scale (hold one length:
  the solver's analysis at the start point cannot see this), and with three planes
  (known or not) the scale about their corner -- four known planes not through one
  point fix it;
* hand-held camera: the target pose and the base frame only together;
* fixture: only the tool point, so the tool orientation trades with the last links.
"""

from __future__ import annotations

import importlib
from typing import Any

#: Public names of the instrument modules, importable from this package (loaded on first use,
#: so importing one instrument does not import them all).
_EXPORTS = {
    "PositionMeasurement": "position", "simulate_positions": "position",
    "PoseMeasurement": "pose", "simulate_poses": "pose",
    "RangeMeasurement": "range", "simulate_range": "range",
    "BearingMeasurement": "bearing", "simulate_bearing": "bearing",
    "CameraMeasurement": "camera", "HandCameraMeasurement": "camera",
    "simulate_camera": "camera",
    "PlaneMeasurement": "plane", "simulate_plane": "plane",
    "FixtureMeasurement": "fixture", "simulate_fixture": "fixture",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)
