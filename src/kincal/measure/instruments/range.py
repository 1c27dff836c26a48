"""Range instruments: distance from a station to the tool point (multilateration).

Measurement equation for row i, seen by station ``k`` at ``s_k`` [m]:

* absolute (time of flight, absolute distance meter, laser tracer)::

      rho_i = |p(q_i) - s_k|

* incremental (laser interferometer: counts the change of distance since it was
  zeroed, at an unknown starting length ``L0`` [m])::

      rho_i = |p(q_i) - s_k| - L0_{k,run}

  Every beam break restarts the count: give the rows after it a new ``run`` label and
  they get their own starting length.

``p = p_e + R_e m`` is the tool point (see :mod:`.common`).  Residuals are
``(rho_pred - rho_obs) / sigma`` [1]; Jacobians ``d rho/dp = u^T``, ``d rho/ds = -u^T``
with ``u = (p - s)/|p - s|``, ``d rho/d L0 = -1``.

Parameters: ``{name}.{station}.x, y, z`` [m] per station, ``{name}.{station}.L0`` (one run)
or ``{name}.{station}.L0.{run}`` [m] per incremental run, then ``{name}.marker.x, y, z``
(``marker="own"``).

What ranges cannot see: with unknown stations, the stations and the robot's base frame
are seen only relative to each other (the stations take the base frame's place).  With
surveyed stations (their parameters held), one station leaves the three rotations of the
robot about it free, two stations the rotation about their common line; three fix the
base frame.  Even a single unknown station identifies the kinematic chain itself given
enough well-spread poses.

File columns: ``station[, mode, run], range, sigma`` (``mode``/``run`` only with incremental
rows).  Simulator: :func:`simulate_range` (stations 1.5-2.5 m around the workspace).
The module registers the ``range`` instrument (:mod:`kincal.measure.registry`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.base import ParamSpec, Triangle, configuration_slices
from kincal.measure.files import Field
from kincal.measure.instruments.common import (
    MARKER_MODES,
    concat_specs,
    label_index_raw,
)
from kincal.measure.instruments.csvio import (
    block_name,
    block_tags,
    build_block,
    choice_column,
    label_column,
    one_block,
    read_block_table,
    write_block_table,
)
from kincal.measure.instruments.placement import (
    POINT_OPTIONS,
    as_flag,
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

Array = NDArray[np.float64]
MODES = ("absolute", "incremental")


class RangeMeasurement(PointBlock):
    """Distances from one or more stations to the tool point.

    Args:
        name: block name (parameter prefix).
        q: (N, n) joint readings [rad / m].
        station: (N,) station label of each reading.
        rho: (N,) measured distance [m] (incremental: change since zeroing).
        sigma: standard deviation [m], scalar or (N,).
        mode: (N,) ``"absolute"`` or ``"incremental"`` per row (default absolute).
        run: (N,) run label of incremental rows (a new run after each beam break).
        marker: ``"own"`` or ``"tool"`` (see :mod:`.common`).
    """

    row_fields = PointBlock.row_fields + ("offset_index", "mode", "run")

    def __init__(self, name: str, q: ArrayLike, station: Sequence[str], rho: ArrayLike,
                 sigma: ArrayLike, mode: Sequence[str] | None = None,
                 run: Sequence[str] | None = None, marker: str = "own") -> None:
        N = self._init_rows("range", name, q, rho, 1, "rho", sigma, marker)
        self._init_stations(station, "station")
        self.mode = ["absolute"] * N if mode is None else [str(m).strip() for m in mode]
        self.run = ["0"] * N if run is None else [str(r).strip() for r in run]
        if len(self.mode) != N or len(self.run) != N or len(self.station_labels) != N:
            raise KincalError(f"block {name!r}: station, mode and run need one entry per row")
        for m in self.mode:
            if m not in MODES:
                raise KincalError(f"block {name!r}: range mode {m!r} is not 'absolute' or "
                                  "'incremental'")
        inc = np.array([m == "incremental" for m in self.mode], dtype=bool)
        # one starting length per (station, run) of incremental rows
        self.offset_index = np.full(N, -1, dtype=np.intp)
        self.offset_names: list[str] = []
        if np.any(inc):
            keys = [f"{s}\t{r}" for s, r, i in
                    zip(self.station_labels, self.run, inc, strict=True) if i]
            groups, idx = label_index_raw(keys)
            self.offset_index[inc] = idx
            stations = [g.split("\t")[0] for g in groups]
            for g, s in zip(groups, stations, strict=True):
                r = g.split("\t")[1]
                single = stations.count(s) == 1
                self.offset_names.append(f"{name}.{s}.L0" if single else f"{name}.{s}.L0.{r}")

    # ------------------------------------------------------------------ model
    def own_parameters(self) -> ParamSpec:
        st = ParamSpec(tuple(f"{self.name}.{s}.{f}" for s in self.stations for f in "xyz"),
                       np.zeros(3 * len(self.stations)), ("m",) * (3 * len(self.stations)),
                       ("instrument",) * (3 * len(self.stations)))
        off = ParamSpec(tuple(self.offset_names), np.zeros(len(self.offset_names)),
                        ("m",) * len(self.offset_names),
                        ("instrument",) * len(self.offset_names))
        return concat_specs([st, off])

    def observe(self, p: Array, own: Array, jacobian: bool
                ) -> tuple[Array, Array | None, Array | None]:
        K = len(self.stations)
        S = own[: 3 * K].reshape(K, 3)
        L0 = own[3 * K:]
        d = p - S[self.station_index]
        rho = np.linalg.norm(d, axis=1)
        has = self.offset_index >= 0
        pred = rho - np.where(has, L0[np.maximum(self.offset_index, 0)] if L0.size else 0.0,
                              0.0)
        if not jacobian:
            return pred[:, None], None, None
        u = d / rho[:, None]
        N = p.shape[0]
        dod = np.zeros((N, 1, own.size))
        cols = 3 * self.station_index[:, None] + np.arange(3)
        np.put_along_axis(dod[:, 0], cols, -u, axis=1)
        rows = np.flatnonzero(has)
        dod[rows, 0, 3 * K + self.offset_index[rows]] = -1.0
        return pred[:, None], u[:, None, :], dod

    def own_guess(self, robot: Robot, p: Array) -> Array:
        """Linear multilateration per station.

        ``|p - s|^2 = (rho + L0)^2`` gives ``2 p.s - |s|^2 + 2 rho L0 + L0^2 = |p|^2 - rho^2``,
        linear in ``s``, ``|s|^2``, and ``L0``, ``L0^2`` per incremental run (treated as
        independent unknowns), solved by least squares; then refined by Gauss-Newton.
        """
        K = len(self.stations)
        S = np.zeros((K, 3))
        L0 = np.zeros(len(self.offset_names))
        rho = self.obs[:, 0]
        for k in range(K):
            rows = np.flatnonzero(self.station_index == k)
            offs = sorted(set(self.offset_index[rows][self.offset_index[rows] >= 0].tolist()))
            # unknowns: s (3), c = |s|^2, then per run: e_j = L0_j, f_j = L0_j^2 (linearised);
            # the system [A | b] folded into its QR triangle in pieces of rows
            nx = 4 + 2 * len(offs)
            tri = Triangle(nx + 1)
            for cs in configuration_slices(rows.size, 1):
                rk = rows[cs]
                A = np.zeros((rk.size, nx + 1))
                A[:, :3] = 2 * p[rk]
                A[:, 3] = -1.0
                A[:, nx] = np.sum(p[rk] ** 2, axis=1) - rho[rk] ** 2
                for j, o in enumerate(offs):
                    sel = self.offset_index[rk] == o
                    A[sel, 4 + 2 * j] = 2 * rho[rk][sel]   # 2 rho L0
                    A[sel, 5 + 2 * j] = 1.0                # L0^2
                tri.add(A)
            # least squares as numpy.linalg.lstsq's default (rcond: eps * max(M, n))
            x = tri.solve(nx, rcond=np.finfo(float).eps * max(rows.size, nx))[:, 0]
            S[k] = x[:3]
            for j, o in enumerate(offs):
                L0[o] = x[4 + 2 * j]
        return np.concatenate([S.reshape(-1), L0])

    def errors(self, robot: Robot, extra: Array) -> dict[str, Array]:
        r = self.evaluate(robot, extra, jacobian=False)[0]
        return {"range_m": r * self.sigma}


# ---------------------------------------------------------------------------- file columns
RANGE_FIELDS = (Field("range", "length", "range (distance, or change of distance)"),
                Field("sigma", "length", "sigma (standard deviation of the range)"))


def write_range(blocks: Sequence[Any], path: str | Path, units: Mapping[str, str] | None = None,
                robot: Any = None) -> None:
    """``station[, mode, run], range, sigma`` per row (mode/run only with incremental rows)."""
    b: RangeMeasurement = one_block(blocks, "range")
    cols: list[tuple[str, Any, str]] = [("station", b.station_labels, "text")]
    if any(m == "incremental" for m in b.mode):
        cols += [("mode", b.mode, "text"), ("run", b.run, "text")]
    cols += [("range", b.obs[:, 0], "length"), ("sigma", b.sigma, "length")]
    write_block_table(path, block_tags("range", b, marker=b.marker), b.q, cols, units, robot,
                      ["range = |p - station| (absolute) or |p - station| - L0 (incremental, "
                       "L0 per station and run)"])


def read_range(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
               ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    """Read a ``range`` CSV into one block (SI units); a bad file raises one line
    naming the file and the line (:class:`~kincal.errors.MeasurementFileError`)."""
    tab = read_block_table(path, robot, "range", RANGE_FIELDS, ("range", "sigma"),
                           {"station": None, "mode": "absolute", "run": "0"}, units, ignore)
    label_column(tab, "station", "station")
    mode = choice_column(tab, "mode", MODES)
    marker = tab.option("marker", "own", MARKER_MODES)
    return [build_block(tab, lambda: RangeMeasurement(
        block_name(tab, name, "range"), tab.q, tab.text["station"], tab.values["range"],
        tab.values["sigma"], mode, tab.text["run"], marker))]


# ---------------------------------------------------------------------------- simulation
def simulate_range(true_robot: Robot, rng: np.random.Generator, n_poses: int, noise: float,
                   stations: int = 4, incremental: bool = False, marker: str = "own",
                   name: str = "range", margin: float = 0.05,
                   truth: Mapping[str, float] | None = None) -> tuple[list[Any], dict[str, float]]:
    """Distances from ``stations`` stations to the tool marker at every pose.

    ``rho = |p - s_k| (- L0_k)`` + N(0, noise^2) [m]; incremental stations were zeroed at
    a random home configuration (``L0_k`` its distance).
    """
    if int(stations) < 1:
        raise MeasurementFileError("option stations must be >= 1")
    incremental = as_flag(incremental, "incremental")
    labels = labels_for(stations, "s")
    K = len(labels)
    q = random_configurations(true_robot, n_poses, rng, margin)
    mode = "incremental" if incremental else "absolute"
    st = np.repeat(np.array(labels)[None], len(q), 0).reshape(-1).tolist()
    qq = np.repeat(q, K, axis=0)
    sigma = stated_sigma(noise, "m")
    probe = RangeMeasurement(name, qq, st, np.zeros(len(qq)), sigma, [mode] * len(qq),
                             marker=marker)
    names = probe.parameters().names
    if truth is not None:
        values = truth_values(truth, names)
    else:
        centre, radius = workspace(true_robot, rng, margin)
        S = stations_around(rng, centre, K, (1.5, 2.5), (-0.4, 0.8))
        L0 = np.zeros(0)
        if incremental:
            home = random_configurations(true_robot, 1, rng, margin)
            L0 = np.linalg.norm(tool_points(true_robot, home, None)[0] - S, axis=1)
        values = np.concatenate([S.reshape(-1), L0] + ([marker_truth(rng)]
                                                      if marker == "own" else []))
    probe_e = probe.evaluate(true_robot, values, jacobian=False)[0] * sigma   # pred - 0
    rho = probe_e + (rng.normal(0.0, noise, len(qq)) if noise > 0 else 0.0)
    block = RangeMeasurement(name, qq, st, rho, sigma, [mode] * len(qq), marker=marker)
    return [block], dict(zip(names, values.tolist(), strict=True))


register(Instrument(
    name="range",
    description="distances from stations to the tool point (ADM, time of flight, "
                "interferometer)",
    simulate=simulate_range, write=write_range, read=read_range,
    options={"stations": (4, "number of range stations"),
             "incremental": (False, "interferometer: distance change from an unknown start"),
             "name": ("range", "block name (prefix of its parameters)"), **POINT_OPTIONS},
    noise_unit="m"))
