"""Measurement technologies beyond position and pose: range, bearing, camera, plane, fixture.

Each instrument is a :class:`~kincal.measure.base.MeasurementModel` (whitened residuals,
analytic Jacobians for every robot parameter and for its own parameters, closed-form
initial guess), a simulator, and a CSV format; importing this package registers them
in :mod:`kincal.measure.registry` for ``kincal simulate --instrument NAME`` and
``kincal calibrate --data file.csv``.

========  ==========================================  =====================================
name      model (module)                              block parameters
========  ==========================================  =====================================
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

from kincal.measure.instruments.bearing import BearingMeasurement
from kincal.measure.instruments.camera import CameraMeasurement, HandCameraMeasurement
from kincal.measure.instruments.files import (
    read_bearing,
    read_camera,
    read_fixture,
    read_plane,
    read_range,
    write_bearing,
    write_camera,
    write_fixture,
    write_plane,
    write_range,
)
from kincal.measure.instruments.fixture import FixtureMeasurement
from kincal.measure.instruments.plane import PlaneMeasurement
from kincal.measure.instruments.range import RangeMeasurement
from kincal.measure.instruments.simulate import (
    simulate_bearing,
    simulate_camera,
    simulate_range,
)
from kincal.measure.instruments.simulate_contact import simulate_fixture, simulate_plane
from kincal.measure.registry import Instrument, register

__all__ = ["RangeMeasurement", "BearingMeasurement", "CameraMeasurement",
           "HandCameraMeasurement", "PlaneMeasurement", "FixtureMeasurement",
           "simulate_range", "simulate_bearing", "simulate_camera", "simulate_plane",
           "simulate_fixture"]

_COMMON = {
    "marker": ("own", "'own': the block's marker parameters; 'tool': the robot's tool "
                      "origin (share one marker between instruments)"),
    "margin": (0.05, "fraction of each joint range kept away from the limits"),
}

register(Instrument(
    name="range",
    description="distances from stations to the tool point (ADM, time of flight, "
                "interferometer)",
    simulate=simulate_range, write=write_range, read=read_range,
    options={"stations": (4, "number of range stations"),
             "incremental": (False, "interferometer: distance change from an unknown start"),
             "name": ("range", "block name (prefix of its parameters)"), **_COMMON},
    noise_unit="m"))

register(Instrument(
    name="bearing",
    description="horizontal and vertical angles from theodolite stations",
    simulate=simulate_bearing, write=write_bearing, read=read_bearing,
    options={"stations": (2, "number of theodolites"),
             "name": ("theodolite", "block name (prefix of its parameters)"), **_COMMON},
    noise_unit="rad"))

register(Instrument(
    name="camera",
    description="pixel coordinates from calibrated pinhole cameras (fixed, or on the hand)",
    simulate=simulate_camera, write=write_camera, read=read_camera,
    options={"mount": ("fixed", "'fixed': cameras watch a tool marker; 'hand': the camera "
                                "is the tool frame and watches a fixed target"),
             "cameras": (2, "number of fixed cameras"),
             "focal_px": (2000.0, "focal length [px]"),
             "width_px": (2048, "image width [px]"), "height_px": (1536, "image height [px]"),
             "grid": (5, "hand-held: target points per side"),
             "spacing_mm": (40.0, "hand-held: target pitch [mm]"),
             "name": ("camera", "block name (prefix of its parameters)"), **_COMMON},
    noise_unit="px"))

register(Instrument(
    name="plane",
    description="contacts of the tool point with known or unknown planes",
    simulate=simulate_plane, write=write_plane, read=read_plane,
    options={"planes": (4, "number of planes"),
             "known": (False, "planes known (True) or estimated (False)"),
             "name": ("plane", "block name (prefix of its parameters)"), **_COMMON},
    noise_unit="m", same_placement=False))

register(Instrument(
    name="fixture",
    description="the tool point on pre-calibrated fixture points of the workspace",
    simulate=simulate_fixture, write=write_fixture, read=read_fixture,
    options={"points": (8, "number of fixture points"),
             "name": ("fixture", "block name (prefix of its parameters)"), **_COMMON},
    noise_unit="m"))
