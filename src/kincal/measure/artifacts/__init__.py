"""Artifact calibration: a probe on the flange seated in the sockets of a rigid artifact.

No instrument measures positions: the data are joint readings taken with the probe
tip seated in the sockets of a rigid artifact whose geometry is (partly) known.

* :mod:`.geometry` - the artifact: sockets, known distances, right angles; YAML;
* :mod:`.probe` - the probe tip (length along flange z, 3-vector, or the robot's tool);
* :mod:`.coincidence` - several seatings of one socket: one point (parameters or
  eliminated by Helmert contrasts);
* :mod:`.distance`, :mod:`.perpendicularity` - the constraints between sockets;
* :mod:`.model` - :class:`ArtifactMeasurement`, the measurement block for the solver;
* :mod:`.simulate` - place the artifact, seat the probe by IK, add encoder noise;
* :mod:`.files` - CSV files (placement, point, joints) and plain per-socket files.

Importing this package registers the instruments ``cross-bar``, ``ball-bar``,
``two-socket`` (and ``artifact`` for files with a geometry YAML) with
:mod:`kincal.measure.registry`.
"""

from __future__ import annotations

from typing import Any

from kincal.measure.artifacts.files import (
    SocketData,
    merge_blocks,
    read_artifact,
    read_socket_files,
    read_socket_folder,
    write_artifact,
)
from kincal.measure.artifacts.geometry import (
    ArtifactGeometry,
    Distance,
    Perpendicular,
    read_geometry,
    write_geometry,
)
from kincal.measure.artifacts.model import ArtifactMeasurement, ConstraintValues
from kincal.measure.artifacts.probe import Probe
from kincal.measure.artifacts.simulate import (
    simulate_artifact,
    simulate_ball_bar,
    simulate_cross_bar,
    simulate_two_socket,
)
from kincal.measure.registry import Instrument, register

__all__ = ["ArtifactGeometry", "Distance", "Perpendicular", "ArtifactMeasurement",
           "ConstraintValues", "Probe", "SocketData", "read_artifact", "write_artifact",
           "merge_blocks", "read_socket_files", "read_socket_folder", "read_geometry",
           "write_geometry",
           "simulate_artifact", "OPTIONS"]

#: Options shared by the three simulators: ``{name: (default, help)}``.
OPTIONS: dict[str, tuple[Any, str]] = {
    "placements": (0, "artifact placements (0: poses / (sockets x visits))"),
    "probe": ("known", "probe tip: known (length along flange z), length or vector "
                       "(identified), tool (the robot's tool origin)"),
    "probe_length_mm": (100.0, "probe length along the flange z axis [mm]"),
    "probe_error_mm": (0.5, "true tip error when the probe is identified [mm]"),
    "encoder_noise_deg": (-1.0, "encoder noise per joint [deg] (< 0: use --noise)"),
    "seat_noise_mm": (0.0, "seating repeatability of the tip, per coordinate [mm]"),
    "length_std_mm": (0.0, "stated uncertainty of the artifact's length [mm]"),
    "visits": (1, "seatings per socket and placement (> 1: coincidence data)"),
    "sockets": ("eliminate", "socket points: eliminate (means) or parameters"),
    "cone_deg": (30.0, "largest tilt of the probe from the socket axis [deg]"),
    "tilt_deg": (20.0, "tilt of the artifact from the probe at its centre [deg]"),
    "margin": (0.05, "fraction of each joint range kept away from the limits"),
    "name": ("", "block name (default cross, ballbar, sockets)"),
}


def _options(**extra: tuple[Any, str]) -> dict[str, tuple[Any, str]]:
    return {**OPTIONS, **extra}


register(Instrument(
    name="cross-bar",
    description="probe seated in the sockets A, B, C, D of a cross, |AC| = |BD| = L, "
                "AC perpendicular to BD (the staged-selection procedure)",
    simulate=simulate_cross_bar, write=write_artifact, read=read_artifact,
    options=_options(bar_length_mm=(300.0, "arm length |AC| = |BD| [mm]"),
                     angle_std_deg=(0.0, "stated uncertainty of the right angle [deg]")),
    noise_unit="rad"))

register(Instrument(
    name="ball-bar",
    description="probe seated in the two sockets of a bar of known length",
    simulate=simulate_ball_bar, write=write_artifact, read=read_artifact,
    options=_options(bar_length_mm=(200.0, "distance between the two sockets [mm]")),
    noise_unit="rad"))

register(Instrument(
    name="two-socket",
    description="probe seated many times in each of two sockets a known distance apart "
                "(coincidence + distance; MUKCa tool)",
    simulate=simulate_two_socket, write=write_artifact, read=read_artifact,
    options={k: v for k, v in _options(
        socket_distance_mm=(50.0, "distance between the socket centres [mm]"),
        visits=(15, "seatings per socket and placement")).items()},
    noise_unit="rad"))


def _no_simulation(*args: Any, **kwargs: Any) -> Any:
    from kincal.errors import KincalError

    raise KincalError("simulate a custom artifact with kincal.measure.artifacts."
                      "simulate_artifact and a geometry with a layout")


register(Instrument(
    name="artifact",
    description="probe seated in the sockets of an artifact described by a geometry YAML",
    simulate=_no_simulation, write=write_artifact, read=read_artifact, options={},
    noise_unit="rad"))
