"""Writers and readers of the instrument CSV files (formats in the package docstring).

Every reader returns ``[block]`` in SI units and raises
:class:`~kincal.errors.MeasurementFileError` -- one line naming the file and the line --
for a bad file; every writer writes one block atomically in the units asked
(``{"length": "mm", "angle": "deg"}``; default SI).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.measure.base import Provenance
from kincal.measure.files import Field, read_header
from kincal.measure.instruments.bearing import BearingMeasurement
from kincal.measure.instruments.camera import CameraMeasurement, HandCameraMeasurement
from kincal.measure.instruments.common import MARKER_MODES, label_index, label_index_raw
from kincal.measure.instruments.csvio import (
    BlockTable,
    one_block,
    per_group,
    read_block_table,
    text_per_group,
    write_block_table,
)
from kincal.measure.instruments.fixture import FixtureMeasurement
from kincal.measure.instruments.plane import (
    PlaneMeasurement,
    angles_from_normal,
    normal_from_angles,
)
from kincal.measure.instruments.range import MODES as RANGE_MODES
from kincal.measure.instruments.range import RangeMeasurement

Array = NDArray[np.float64]

RANGE_FIELDS = (Field("range", "length", "range (distance, or change of distance)"),
                Field("sigma", "length", "sigma (standard deviation of the range)"))
BEARING_FIELDS = (Field("az", "angle", "az (horizontal angle)"),
                  Field("el", "angle", "el (elevation)"),
                  Field("sigma", "angle", "sigma (standard deviation of each angle)"))
INTRINSICS = ("fx", "fy", "cx", "cy")
CAMERA_FIELDS = (Field("u", "pixel", "u (image column)"), Field("v", "pixel", "v (image row)"),
                 *(Field(k, "pixel", f"{k} (intrinsics)") for k in INTRINSICS),
                 Field("sigma", "pixel", "sigma (standard deviation of u and v)"))
HAND_FIELDS = CAMERA_FIELDS + tuple(Field(f"target_{c}", "length", f"target_{c} (target "
                                          "point in the target frame)") for c in "xyz")
PLANE_FIELDS = (Field("n_az", "angle", "n_az (azimuth of the plane normal)"),
                Field("n_el", "angle", "n_el (elevation of the plane normal)"),
                Field("d", "length", "d (plane offset: n.p = d)"),
                Field("sigma", "length", "sigma (standard deviation of the contact)"))
FIXTURE_FIELDS = (*(Field(c, "length", f"{c} (fixture point, world frame)") for c in "xyz"),
                  Field("sigma", "length", "sigma (standard deviation per coordinate)"))


# ---------------------------------------------------------------------------- helpers
def _labels(tab: BlockTable, key: str, what: str) -> tuple[tuple[str, ...], NDArray[np.intp]]:
    """Labels of a text column, with the line of the first bad one in the error."""
    vals = tab.text[key]
    try:
        return label_index(vals, what, "file")
    except KincalError:
        distinct, idx = label_index_raw(vals)
        bad = [g for g, s in enumerate(distinct) if not _valid_label(s, what)]
        r = int(np.argmax(np.isin(idx, bad)))
        raise tab.error(r, f"column {key}: {what} label {vals[r]!r} must be a word (letters, "
                           "digits, _ - .) other than 'marker'") from None


def _valid_label(s: str, what: str) -> bool:
    try:
        label_index([s], what, "file")
    except KincalError:
        return False
    return True


def _choice(tab: BlockTable, key: str, choices: Sequence[str]) -> list[str]:
    vals = tab.text[key]
    bad = ~np.isin(np.array(vals, dtype=str), list(choices))
    if np.any(bad):
        r = int(np.argmax(bad))
        raise tab.error(r, f"column {key}: {vals[r]!r} is not one of {', '.join(choices)}")
    return list(vals)


def _build(tab: BlockTable, make: Any) -> Any:
    try:
        block = make()
        block.provenance = Provenance(str(tab.table.path), tab.table)  # the CLI lists the
        # bookkeeping columns it skipped
        return block
    except MeasurementFileError:
        raise
    except KincalError as exc:
        raise MeasurementFileError(str(exc), source=tab.table.path) from None


def _name(tab: BlockTable, name: str | None, default: str) -> str:
    return name or tab.tags.get("name") or default


def _tags(instrument: str, block: Any, **extra: str) -> dict[str, str]:
    return {"instrument": instrument, "name": block.name, **extra}


def _stack(values: Mapping[str, Array], keys: Sequence[str]) -> Array:
    return np.column_stack([values[k] for k in keys])


# ---------------------------------------------------------------------------- range
def write_range(blocks: Sequence[Any], path: str | Path, units: Mapping[str, str] | None = None,
                robot: Any = None) -> None:
    """``station[, mode, run], range, sigma`` per row (mode/run only with incremental rows)."""
    b: RangeMeasurement = one_block(blocks, "range")
    cols: list[tuple[str, Any, str]] = [("station", b.station_labels, "text")]
    if any(m == "incremental" for m in b.mode):
        cols += [("mode", b.mode, "text"), ("run", b.run, "text")]
    cols += [("range", b.obs[:, 0], "length"), ("sigma", b.sigma, "length")]
    write_block_table(path, _tags("range", b, marker=b.marker), b.q, cols, units, robot,
                      ["range = |p - station| (absolute) or |p - station| - L0 (incremental, "
                       "L0 per station and run)"])


def read_range(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
               ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    tab = read_block_table(path, robot, "range", RANGE_FIELDS, ("range", "sigma"),
                           {"station": None, "mode": "absolute", "run": "0"}, units, ignore)
    _labels(tab, "station", "station")
    mode = _choice(tab, "mode", RANGE_MODES)
    marker = tab.option("marker", "own", MARKER_MODES)
    return [_build(tab, lambda: RangeMeasurement(
        _name(tab, name, "range"), tab.q, tab.text["station"], tab.values["range"],
        tab.values["sigma"], mode, tab.text["run"], marker))]


# ---------------------------------------------------------------------------- bearing
def write_bearing(blocks: Sequence[Any], path: str | Path,
                  units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """``station, az, el, sigma`` per row."""
    b: BearingMeasurement = one_block(blocks, "bearing")
    cols = [("station", b.station_labels, "text"), ("az", b.obs[:, 0], "angle"),
            ("el", b.obs[:, 1], "angle"), ("sigma", b.sigma, "angle")]
    write_block_table(path, _tags("bearing", b, marker=b.marker), b.q, cols, units, robot,
                      ["az = atan2(y, x), el = atan2(z, hypot(x, y)) of the point in the "
                       "station frame (z up)"])


def read_bearing(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                 ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    tab = read_block_table(path, robot, "bearing", BEARING_FIELDS, ("az", "el", "sigma"),
                           {"station": None}, units, ignore)
    _labels(tab, "station", "station")
    marker = tab.option("marker", "own", MARKER_MODES)
    return [_build(tab, lambda: BearingMeasurement(
        _name(tab, name, "theodolite"), tab.q, tab.text["station"],
        _stack(tab.values, ("az", "el")), tab.values["sigma"], marker))]


# ---------------------------------------------------------------------------- camera
def write_camera(blocks: Sequence[Any], path: str | Path,
                 units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """Fixed: ``station, u, v, fx, fy, cx, cy, sigma``; hand-held: ``target_x/y/z`` instead
    of ``station``."""
    b = one_block(blocks, "camera")
    K = np.asarray(b.K, dtype=float)
    if isinstance(b, HandCameraMeasurement):
        cols: list[tuple[str, Any, str]] = [(f"target_{c}", b.s[:, i], "length")
                                            for i, c in enumerate("xyz")]
        tags = _tags("camera", b, mount="hand")
    else:
        cols = [("station", b.station_labels, "text")]
        tags = _tags("camera", b, mount="fixed", marker=b.marker)
    cols += [("u", b.obs[:, 0], "pixel"), ("v", b.obs[:, 1], "pixel")]
    cols += [(k, K[:, i], "pixel") for i, k in enumerate(INTRINSICS)]
    cols.append(("sigma", b.sigma, "pixel"))
    write_block_table(path, tags, b.q, cols, units, robot,
                      ["u = fx x/z + cx, v = fy y/z + cy (undistorted pixels; camera z "
                       "forward)"])


def read_camera(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    mount = read_header(path)[0].get("mount", "fixed")
    hand = mount == "hand"
    fields = HAND_FIELDS if hand else CAMERA_FIELDS
    req = ("u", "v", *INTRINSICS, "sigma") + (("target_x", "target_y", "target_z")
                                               if hand else ())
    tab = read_block_table(path, robot, "camera", fields, req,
                           {} if hand else {"station": None}, units, ignore)
    tab.option("mount", "fixed", ("fixed", "hand"))
    uv = _stack(tab.values, ("u", "v"))
    K = _stack(tab.values, INTRINSICS)
    if np.any(K[:, :2] <= 0):
        r = int(np.argmax(np.any(K[:, :2] <= 0, axis=1)))
        raise tab.error(r, "focal lengths fx, fy must be positive")
    if hand:
        Kc = per_group(tab, np.zeros(len(K), dtype=np.intp), K, "camera intrinsics")[0]
        return [_build(tab, lambda: HandCameraMeasurement(
            _name(tab, name, "camera"), tab.q, _stack(tab.values, ("target_x", "target_y",
                                                                   "target_z")),
            uv, tab.values["sigma"], Kc))]
    stations, idx = _labels(tab, "station", "camera")
    Kg = per_group(tab, idx, K, "camera intrinsics")
    marker = tab.option("marker", "own", MARKER_MODES)
    return [_build(tab, lambda: CameraMeasurement(
        _name(tab, name, "camera"), tab.q, tab.text["station"], uv, tab.values["sigma"],
        {s: tuple(Kg[g]) for g, s in enumerate(stations)}, marker))]


# ---------------------------------------------------------------------------- plane
def write_plane(blocks: Sequence[Any], path: str | Path, units: Mapping[str, str] | None = None,
                robot: Any = None) -> None:
    """``plane, mode, n_az, n_el, d, sigma`` per contact (the plane, or its nominal)."""
    b: PlaneMeasurement = one_block(blocks, "plane")
    defs = [b.plane_defs[s] for s in b.planes]
    ang = angles_from_normal(np.array([d[0] for d in defs]))[b.plane_index]
    d = np.array([x[1] for x in defs])[b.plane_index]
    mode = ["known" if defs[g][2] else "unknown" for g in b.plane_index]
    cols = [("plane", b.plane_labels, "text"), ("mode", mode, "text"),
            ("n_az", ang[:, 0], "angle"), ("n_el", ang[:, 1], "angle"), ("d", d, "length"),
            ("sigma", b.sigma, "length")]
    write_block_table(path, _tags("plane", b, marker=b.marker), b.q, cols, units, robot,
                      ["contact: n.p = d, n = (cos el cos az, cos el sin az, sin el); an "
                       "unknown plane's n and d are nominal values"])


def read_plane(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
               ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    tab = read_block_table(path, robot, "plane", PLANE_FIELDS, ("n_az", "n_el", "d", "sigma"),
                           {"plane": None, "mode": "unknown"}, units, ignore)
    planes, idx = _labels(tab, "plane", "plane")
    _choice(tab, "mode", ("known", "unknown"))
    g = per_group(tab, idx, _stack(tab.values, ("n_az", "n_el", "d")), "plane n_az, n_el, d")
    modes = text_per_group(tab, idx, tab.text["mode"], "plane mode")
    defs = {s: (normal_from_angles(g[k, 0], g[k, 1]), float(g[k, 2]), modes[k] == "known")
            for k, s in enumerate(planes)}
    marker = tab.option("marker", "own", MARKER_MODES)
    return [_build(tab, lambda: PlaneMeasurement(
        _name(tab, name, "plane"), tab.q, tab.text["plane"], tab.values["sigma"], defs,
        marker))]


# ---------------------------------------------------------------------------- fixture
def write_fixture(blocks: Sequence[Any], path: str | Path,
                  units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """``x, y, z, sigma`` per contact: the fixture point in the world frame."""
    b: FixtureMeasurement = one_block(blocks, "fixture")
    cols = [(c, b.obs[:, i], "length") for i, c in enumerate("xyz")]
    cols.append(("sigma", b.sigma, "length"))
    write_block_table(path, _tags("fixture", b, marker=b.marker), b.q, cols, units, robot,
                      ["x, y, z = the known fixture point the tool point sits on (world)"])


def read_fixture(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                 ignore: Sequence[str] = (), name: str | None = None) -> list[Any]:
    tab = read_block_table(path, robot, "fixture", FIXTURE_FIELDS, ("x", "y", "z", "sigma"),
                           {}, units, ignore)
    marker = tab.option("marker", "own", MARKER_MODES)
    return [_build(tab, lambda: FixtureMeasurement(
        _name(tab, name, "fixture"), tab.q, _stack(tab.values, "xyz"), tab.values["sigma"],
        marker))]
