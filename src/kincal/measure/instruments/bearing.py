"""Bearing instruments: a theodolite's two angles to the tool point (triangulation).

Each station ``k`` has a pose ``T_k = Trans(x, y, z) Rz(rz) Ry(ry) Rx(rx)`` in the world
(its z axis is the instrument's vertical axis, its x axis the zero of the horizontal
circle).  The tool point in the station frame is ``x = R_k^T (p(q) - t_k)`` and the
measurement equations are [rad]::

    az = atan2(x_2, x_1)                    horizontal angle, counter-clockwise about z
    el = atan2(x_3, sqrt(x_1^2 + x_2^2))    elevation above the horizontal plane

(a theodolite reading clockwise horizontal directions ``Hz`` and zenith angles ``V``
gives ``az = -Hz``, ``el = pi/2 - V``).  Residuals are ``(az_pred - az_obs) / sigma``,
wrapped to (-pi, pi], and ``(el_pred - el_obs) / sigma``.  Jacobians, with
``h = sqrt(x_1^2 + x_2^2)``, ``r = |x|``::

    d az/dx = (-x_2, x_1, 0) / h^2
    d el/dx = (-x_1 x_3 / h, -x_2 x_3 / h, h) / r^2

chained with ``dx/dp = R_k^T`` and ``dx/d(station)`` from :func:`.common.to_local`.

Parameters: ``{name}.{station}.x, y, z, rz, ry, rx`` [m, rad] per station, then the marker
``{name}.marker.x, y, z`` (``marker="own"``).

What angles cannot see: angles do not change when the whole scene is scaled about a
station, so bearings alone never fix the scale (one robot length or the station
baseline must be known, or a range instrument fused); one station also cannot separate
its own pose from the robot's base frame.

File columns: ``station, az, el, sigma``.  Simulator: :func:`simulate_bearing` (levelled
theodolites 2-3 m around the workspace).
The module registers the ``bearing`` instrument (:mod:`kincal.measure.registry`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import MeasurementFileError
from kincal.measure.base import ParamSpec
from kincal.measure.files import Field
from kincal.measure.instruments.common import (
    MARKER_MODES,
    concat_specs,
    frame_spec,
    station_columns,
    station_poses_from_directions,
    to_local,
)
from kincal.measure.instruments.csvio import (
    block_name,
    block_tags,
    build_block,
    label_column,
    one_block,
    read_block_table,
    stack_columns,
    write_block_table,
)
from kincal.measure.instruments.placement import (
    POINT_OPTIONS,
    labels_for,
    marker_truth,
    stated_sigma,
    stations_around,
    tool_points,
    truth_values,
    workspace,
)
from kincal.measure.instruments.pointblock import PointBlock
from kincal.measure.registry import Instrument, register
from kincal.measure.simulate import random_configurations
from kincal.robots.chain import Robot
from kincal.spatial import wrap_angle

Array = NDArray[np.float64]


wrap = wrap_angle   # (-pi, pi]


def bearing_angles(x: Array, jacobian: bool) -> tuple[Array, Array | None]:
    """``(az, el)`` (N, 2) [rad] of points ``x`` (N, 3) in a station frame, and d/dx (N, 2, 3)."""
    h2 = x[:, 0] ** 2 + x[:, 1] ** 2
    h = np.sqrt(h2)
    ang = np.column_stack([np.arctan2(x[:, 1], x[:, 0]), np.arctan2(x[:, 2], h)])
    if not jacobian:
        return ang, None
    r2 = h2 + x[:, 2] ** 2
    D = np.zeros((x.shape[0], 2, 3))
    D[:, 0, 0] = -x[:, 1] / h2
    D[:, 0, 1] = x[:, 0] / h2
    D[:, 1, 0] = -x[:, 0] * x[:, 2] / (h * r2)
    D[:, 1, 1] = -x[:, 1] * x[:, 2] / (h * r2)
    D[:, 1, 2] = h / r2
    return ang, D


def bearing_directions(ang: Array) -> Array:
    """Unit directions (N, 3) of ``(az, el)`` (N, 2) in the station frame."""
    ce = np.cos(ang[:, 1])
    return np.column_stack([ce * np.cos(ang[:, 0]), ce * np.sin(ang[:, 0]), np.sin(ang[:, 1])])


class BearingMeasurement(PointBlock):
    """Horizontal and vertical angles from one or more theodolite stations.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        station: (N,) station label of each reading.
        angles: (N, 2) measured ``(az, el)`` [rad].
        sigma: standard deviation of each angle [rad], scalar or (N,).
        marker: ``"own"`` or ``"tool"`` (see :mod:`.common`).
    """

    SIGMA_UNIT = "rad"

    def __init__(self, name: str, q: ArrayLike, station: Sequence[str], angles: ArrayLike,
                 sigma: ArrayLike, marker: str = "own") -> None:
        N = self._init_rows("bearing", name, q, angles, 2, "angles", sigma, marker)
        self._init_stations(station, "station", N)

    def own_parameters(self) -> ParamSpec:
        return concat_specs([frame_spec(f"{self.name}.{s}") for s in self.stations])

    def difference(self, pred: Array) -> Array:
        d = pred - self.obs
        d[:, 0] = wrap(d[:, 0])
        return d

    def observe(self, p: Array, own: Array, jacobian: bool
                ) -> tuple[Array, Array | None, Array | None]:
        frames = own.reshape(-1, 6)
        x, dxdp, dxds = to_local(frames, self.station_index, p, jacobian)
        ang, D = bearing_angles(x, jacobian)
        if not jacobian:
            return ang, None, None
        assert D is not None and dxdp is not None and dxds is not None
        return ang, D @ dxdp, station_columns(self.station_index, D @ dxds, own.size)

    def own_guess(self, robot: Robot, p: Array) -> Array:
        """Each station's pose by the linear direction DLT (:func:`.common.direction_pose`)."""
        return station_poses_from_directions(self.stations, self.station_index,
                                             bearing_directions(self.obs), p, "station",
                                             self.name)

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0].reshape(-1, 2)
        return {"angle_rad": np.hypot(r[:, 0], r[:, 1]) * self.sigma}


# ---------------------------------------------------------------------------- file columns
BEARING_FIELDS = (Field("az", "angle", "az (horizontal angle)"),
                  Field("el", "angle", "el (elevation)"),
                  Field("sigma", "angle", "sigma (standard deviation of each angle)"))


def write_bearing(blocks: Sequence[Any], path: str | Path,
                  units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """``station, az, el, sigma`` per row."""
    b: BearingMeasurement = one_block(blocks, "bearing")
    cols = [("station", b.station_labels, "text"), ("az", b.obs[:, 0], "angle"),
            ("el", b.obs[:, 1], "angle"), ("sigma", b.sigma, "angle")]
    write_block_table(path, block_tags("bearing", b, marker=b.marker), b.q, cols, units, robot,
                      ["az = atan2(y, x), el = atan2(z, hypot(x, y)) of the point in the "
                       "station frame (z up)"])


def read_bearing(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                 ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``bearing`` CSV into one block (SI units); a bad file raises one line
    naming the file and the line (:class:`~kincal.errors.MeasurementFileError`)."""
    tab = read_block_table(path, robot, "bearing", BEARING_FIELDS, ("az", "el", "sigma"),
                           {"station": None}, units, ignore)
    label_column(tab, "station", "station")
    marker = tab.option("marker", "own", MARKER_MODES)
    return [build_block(tab, lambda: BearingMeasurement(
        block_name(tab, name, "theodolite"), tab.q, tab.text["station"],
        stack_columns(tab.values, ("az", "el")), tab.values["sigma"], marker))]


# ---------------------------------------------------------------------------- simulation
def simulate_bearing(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                     stations: int = 2, marker: str = "own", name: str = "theodolite",
                     margin: float = 0.05, truth: Mapping[str, float] | None = None
                     ) -> tuple[list[Any], dict[str, float]]:
    """Horizontal and vertical angles from ``stations`` levelled theodolites [rad]."""
    if int(stations) < 1:
        raise MeasurementFileError("option stations must be >= 1")
    labels = labels_for(stations, "t")
    K = len(labels)
    q = random_configurations(true_robot, n_poses, rng, margin)
    st = np.repeat(np.array(labels)[None], len(q), 0).reshape(-1).tolist()
    qq = np.repeat(q, K, axis=0)
    sigma = stated_sigma(noise, "rad")
    probe = BearingMeasurement(name, qq, st, np.zeros((len(qq), 2)), sigma, marker=marker)
    names = probe.parameters().names
    if truth is not None:
        values = truth_values(truth, names)
    else:
        centre, _ = workspace(true_robot, rng, margin)
        S = stations_around(rng, centre, K, (2.0, 3.0), (-0.3, 0.3))
        frames = np.column_stack([S, rng.uniform(-np.pi, np.pi, K),
                                  rng.normal(0, 2e-3, (K, 2))])       # levelled to ~0.1 deg
        values = np.concatenate([frames.reshape(-1)] + ([marker_truth(rng)]
                                                        if marker == "own" else []))
    m = values[-3:] if marker == "own" else None
    p = tool_points(true_robot, qq, m)
    x = to_local(values[: 6 * K].reshape(K, 6), probe.station_index, p, False)[0]
    ang = bearing_angles(x, False)[0]
    if noise > 0:
        ang = ang + rng.normal(0.0, noise, ang.shape)
    block = BearingMeasurement(name, qq, st, ang, sigma, marker=marker)
    return [block], dict(zip(names, values.tolist(), strict=True))


register(Instrument(
    name="bearing",
    description="horizontal and vertical angles from theodolite stations",
    simulate=simulate_bearing, write=write_bearing, read=read_bearing,
    options={"stations": (2, "number of theodolites"),
             "name": ("theodolite", "block name (prefix of its parameters)"), **POINT_OPTIONS},
    noise_unit="rad"))
