"""Artifact measurement files: one CSV per block (or per placement), and plain socket files.

Format (see also :mod:`kincal.measure.files` for the shared rules: units in every
numeric header, joint columns named after the robot's joints, one error line naming
file / line / column)::

    # kincal measurements: instrument=cross-bar; length_mm=300; probe=length; probe_length_mm=100
    placement,point,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg
    1,A,12.5,-40.1,...
    1,B,...

* ``placement`` (text, optional): the artifact placement of the row; without it the
  whole file is one placement named after the file (one CSV per placement).
* ``point`` (text; ``socket`` is accepted too): the socket the probe was seated in
  (A, B, C, D for the cross-bar; A, B for the ball-bar; hole_0, hole_1 for the
  two-socket tool; any label of a geometry YAML).  Several rows with the same
  placement and point are seatings of one socket (coincidence).
* Tags on line 1 (all but ``instrument`` optional; lengths and angles carry their unit
  in the key):

  ================================  ===================================================
  ``length_<u>``                    the built-in artifact's length (|AC| = |BD|, |AB|)
  ``length_std_<u>``                its uncertainty (default 0)
  ``angle_std_<u>``                 uncertainty of the cross's right angle (default 0)
  ``geometry=FILE.yaml``            instead: a geometry YAML, relative to the CSV
  ``probe=tool|length|vector``      the probe tip (default ``tool``)
  ``probe_length_<u>``              ``probe=length``: its length along flange z
  ``probe_x_<u> probe_y_<u> ...``   ``probe=vector``: the tip in the end frame
  ``estimate_probe=true|false``     identify the tip (default false)
  ``sockets=eliminate|parameters``  socket points eliminated or as parameters
  ``joint_std_<u>``                 encoder noise per joint (default 0)
  ``point_std_<u>``                 seating repeatability (default 0.01 mm when
                                    ``joint_std`` is 0, else 0)
  ================================  ===================================================

:func:`read_socket_files` reads the plain headerless files of
``shared/data/panda_two_socket`` (one file per socket, one configuration per row,
joint values in the unit the caller names: radians there).
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from kincal.errors import KincalError, MeasurementFileError
from kincal.io import atomic_write_text, read_text
from kincal.measure.artifacts.geometry import (
    ArtifactGeometry,
    read_geometry,
    write_geometry,
)
from kincal.measure.artifacts.model import ArtifactMeasurement
from kincal.measure.artifacts.probe import Probe
from kincal.measure.base import Provenance
from kincal.measure.files import (
    joint_columns,
    read_table,
    tag_quantities,
    tag_quantity,
)
from kincal.units import MAX_SI, UNITS

Array = NDArray[np.float64]

TEXT_COLUMNS = ("placement", "point", "socket")
DEFAULT_POINT_STD = 1e-5


# --------------------------------------------------------------------------- tags
def _bool(tags: Mapping[str, str], key: str, src: str) -> bool:
    v = tags.get(key, "false").strip().lower()
    if v not in ("true", "false", "yes", "no", "1", "0"):
        raise MeasurementFileError(f"line 1: {key}={v!r} is not true or false", source=src)
    return v in ("true", "yes", "1")


def geometry_from_tags(tags: Mapping[str, str], path: str | Path) -> ArtifactGeometry:
    """The artifact geometry named by a file's tags (built-in + length, or a YAML)."""
    src = str(path)
    if "geometry" in tags:
        return read_geometry(Path(path).parent / tags["geometry"])
    kind = tags.get("instrument", "")
    vals = tag_quantities(tags, src)
    try:
        return ArtifactGeometry.builtin(kind, tag_quantity(vals, "length", "length", src),
                                        tag_quantity(vals, "length_std", "length", src, 0.0),
                                        tag_quantity(vals, "angle_std", "angle", src, 0.0))
    except MeasurementFileError:
        raise
    except KincalError as exc:
        raise MeasurementFileError(f"line 1: {exc}", source=src) from None


def probe_from_tags(tags: Mapping[str, str], path: str | Path) -> Probe:
    """The probe described by a file's tags (default: the robot's tool origin)."""
    src = str(path)
    mode = tags.get("probe", "tool")
    vals = tag_quantities(tags, src)
    est = _bool(tags, "estimate_probe", src)
    try:
        if mode == "tool":
            if est:
                raise MeasurementFileError("line 1: probe=tool has nothing to estimate; use "
                                           "probe=length or probe=vector", source=src)
            return Probe.tool()
        if mode == "length":
            return Probe.length(tag_quantity(vals, "probe_length", "length", src), est)
        if mode == "vector":
            return Probe.vector([tag_quantity(vals, f"probe_{c}", "length", src)
                                 for c in "xyz"], est)
    except MeasurementFileError:
        raise
    except KincalError as exc:
        raise MeasurementFileError(f"line 1: {exc}", source=src) from None
    raise MeasurementFileError(f"line 1: probe={mode!r} is not tool, length or vector",
                               source=src)


# --------------------------------------------------------------------------- reading
def _text_columns(path: str | Path, lines: NDArray[np.intp]) -> dict[str, list[str]]:
    """The text columns (placement, point / socket) of the data rows at ``lines``."""
    text = Path(path).read_text(encoding="utf-8-sig").splitlines()
    body = [(i + 1, ln) for i, ln in enumerate(text)
            if ln.strip() and not ln.lstrip().startswith("#")]
    header = [c.strip() for c in next(csv.reader([body[0][1]]))]
    rows = dict(body[1:])
    out: dict[str, list[str]] = {}
    for name in TEXT_COLUMNS:
        if name in header:
            k = header.index(name)
            vals = []
            for ln in lines:
                v = next(csv.reader([rows[int(ln)]]))[k].strip()
                if not v:
                    raise MeasurementFileError(f"line {int(ln)}: column {k + 1} ({name}) is "
                                               "empty", source=str(path))
                vals.append(v)
            out[name] = vals
    return out


def read_artifact(path: str | Path, robot: Any, units: Mapping[str, str] | None = None,
                  ignore: Sequence[str] = (), name: str | None = None,
                  geometry: ArtifactGeometry | None = None, probe: Probe | None = None,
                  sockets: str | None = None) -> list[ArtifactMeasurement]:
    """Read an artifact CSV into one :class:`ArtifactMeasurement` (SI units).

    ``geometry`` / ``probe`` / ``sockets`` override the file's tags.  ``robot`` gives
    the joint columns and propagates ``joint_std`` into the weights.
    """
    t = read_table(path, robot, (), units, ignore)
    tags = t.tags
    text = _text_columns(path, t.lines)
    t.ignored = [c for c in t.ignored if c not in text]       # read, as labels
    point = text.get("point", text.get("socket"))
    if point is None:
        raise t.error("no 'point' column (the socket of each row: A, B, C, D ...)")
    if "point" in text and "socket" in text:
        raise t.error("both 'point' and 'socket' columns: keep one")
    placement = text.get("placement", [Path(path).stem] * len(t))
    geom = geometry or geometry_from_tags(tags, path)
    for i, so in enumerate(point):
        if so not in geom.sockets:
            raise t.error(f"socket {so!r} is not one of the {geom.kind}'s sockets "
                          f"({', '.join(geom.sockets)})", int(t.lines[i]))
    block = _block(t.q, placement, point, tags, path, robot, name, geom, probe, sockets)
    block.provenance = Provenance(str(path), t)
    return [block]


def _block(q: Array, placement: Sequence[str], point: Sequence[str], tags: Mapping[str, str],
           path: str | Path, robot: Any, name: str | None, geom: ArtifactGeometry,
           probe: Probe | None = None, sockets: str | None = None) -> ArtifactMeasurement:
    """The block of an artifact file from its rows and tags (probe, noise, socket mode)."""
    src = str(path)
    prb = probe or probe_from_tags(tags, path)
    vals = tag_quantities(tags, src)
    joint_std = tag_quantity(vals, "joint_std", "angle", src, 0.0)
    point_std = tag_quantity(vals, "point_std", "length", src,
                     DEFAULT_POINT_STD if joint_std == 0 else 0.0)
    mode = sockets or tags.get("sockets", "eliminate")
    try:
        return ArtifactMeasurement(q, list(placement), list(point), geom, prb, mode,
                                   name or tags.get("name") or geom.kind.replace("-", ""),
                                   joint_std=joint_std, point_std=point_std, robot=robot)
    except MeasurementFileError:
        raise
    except KincalError as exc:
        raise MeasurementFileError(str(exc), source=src) from None


def read_socket_folder(path: str | Path, robot: Any, tags: Mapping[str, str],
                       name: str | None = None, angle_unit: str = "rad"
                       ) -> list[ArtifactMeasurement]:
    """A MUKCa-style socket folder as one artifact block (one placement), or a robot's
    folder of such placement folders as one block of several placements (as the MUKCa
    recorder lays them out: ``panda_3/frontleft/hole_0.csv`` ...).

    The folder holds one headerless file per socket (``hole_0.csv``, ``hole_1.csv``:
    one configuration per row, the robot's joints in its order, in ``angle_unit``,
    radians as the MUKCa recorder writes them); the recorder's ``hole_?_pose.csv`` beside
    them (the controller's own pose of the ball) are skipped (:func:`socket_files`).
    Files carry no tag line, so ``tags`` says what the artifact is: ``instrument``
    (default ``two-socket``), its length (``length_mm=50``), the probe (``probe=tool``
    ...), ``point_std_<u>`` and the rest of the artifact tags (module docstring).  The
    placement is the folder's name.
    """
    src = str(path)
    subs = placement_folders(path)
    if subs:                                   # a robot's folder: one placement per folder
        blocks = [read_socket_folder(f, robot, tags, name, angle_unit)[0] for f in subs]
        try:
            return [merge_blocks(blocks, name)]
        except MeasurementFileError:
            raise
        except KincalError as exc:
            raise MeasurementFileError(str(exc), source=src) from None
    data = read_socket_files(socket_files(path), angle_unit=angle_unit,
                             placement=Path(path).name)
    if robot is not None and data.q.shape[1] != robot.n:
        raise MeasurementFileError(f"{data.q.shape[1]} joint values per row, but robot "
                                   f"{robot.name!r} has {robot.n} joints "
                                   f"({', '.join(robot.joint_names)})", source=src)
    tags = {"instrument": "two-socket", **dict(tags)}
    geom = geometry_from_tags(tags, path)
    for so in dict.fromkeys(data.socket):
        if so not in geom.sockets:
            raise MeasurementFileError(f"socket file {so!r} is not one of the {geom.kind}'s "
                                       f"sockets ({', '.join(geom.sockets)}): name the files "
                                       "after them", source=src)
    return [_block(data.q, data.placement, data.socket, tags, path, robot, name, geom)]


#: What the MUKCa recorder writes beside each socket file: the controller's own pose of the
#: ball (its forward kinematics of its nominal model, position and quaternion), not a
#: measurement: skipped on purpose by :func:`socket_files`.
CONTROLLER_POSE_SUFFIX = "_pose"


def placement_folders(folder: str | Path) -> list[Path]:
    """The placement sub-folders of a MUKCa robot folder (each holding socket files), in
    name order; ``[]`` when ``folder`` itself holds socket files (one placement)."""
    root = Path(folder)
    if any(f for f in root.glob("*.csv") if not f.stem.endswith(CONTROLLER_POSE_SUFFIX)):
        return []
    return sorted(d for d in root.iterdir() if d.is_dir() and any(
        f for f in d.glob("*.csv") if not f.stem.endswith(CONTROLLER_POSE_SUFFIX)))


def socket_files(folder: str | Path) -> list[Path]:
    """The socket files of a MUKCa folder: every ``*.csv`` but the controller's pose files
    (``hole_0_pose.csv``: the controller's forward kinematics, which carries no information
    a calibration can use); one error line when none is left."""
    files = sorted(f for f in Path(folder).glob("*.csv")
                   if not f.stem.endswith(CONTROLLER_POSE_SUFFIX))
    if not files:
        raise MeasurementFileError("no socket files (hole_0.csv, hole_1.csv ...) in the "
                                   "folder", source=str(folder))
    return files


def merge_blocks(blocks: Sequence[ArtifactMeasurement], name: str | None = None
                 ) -> ArtifactMeasurement:
    """One block from several (e.g. one CSV per placement) of the same artifact and probe.

    Placement labels must not repeat across the blocks.
    """
    if not blocks:
        raise KincalError("nothing to merge")
    first = blocks[0]
    for b in blocks[1:]:
        if b.geometry != first.geometry or b.probe != first.probe:
            raise KincalError(f"blocks {first.name!r} and {b.name!r} describe different "
                              "artifacts or probes; they cannot be merged")
    seen: set[str] = set()
    for b in blocks:
        clash = seen & set(b.placements)
        if clash:
            raise KincalError(f"placement {sorted(clash)[0]!r} appears in two blocks")
        seen |= set(b.placements)
    return first.replace(
        q=np.concatenate([b.q for b in blocks]),
        placement=[p for b in blocks for p in b.placement_labels],
        socket=[s for b in blocks for s in b.socket_labels],
        name=name or first.name,
        joint_std=max(b.joint_std for b in blocks),
        point_std=max(b.point_std for b in blocks))


# --------------------------------------------------------------------------- writing
def _fmt(v: float) -> str:
    return f"{v:.15g}"


def artifact_tags(block: ArtifactMeasurement, length_unit: str, angle_unit: str,
                  geometry_file: str | None = None) -> dict[str, str]:
    """Line-1 tags describing a block (see the module docstring)."""
    fl, fa = 1.0 / UNITS[length_unit][1], 1.0 / UNITS[angle_unit][1]
    g = block.geometry
    tags = {"instrument": g.kind if g.kind != "custom" else "artifact", "name": block.name}
    if geometry_file:
        tags["geometry"] = geometry_file
    else:
        tags[f"length_{length_unit}"] = _fmt(g.length * fl)
        if g.distances[0].std:
            tags[f"length_std_{length_unit}"] = _fmt(g.distances[0].std * fl)
        if g.perpendiculars and g.perpendiculars[0].std:
            tags[f"angle_std_{angle_unit}"] = _fmt(g.perpendiculars[0].std * fa)
    p = block.probe
    tags["probe"] = p.mode
    if p.mode == "length":
        tags[f"probe_length_{length_unit}"] = _fmt(p.value[0] * fl)
    elif p.mode == "vector":
        for c, v in zip("xyz", p.value, strict=True):
            tags[f"probe_{c}_{length_unit}"] = _fmt(v * fl)
    if p.estimate:
        tags["estimate_probe"] = "true"
    tags["sockets"] = block.sockets
    tags[f"joint_std_{angle_unit}"] = _fmt(block.joint_std * fa)
    tags[f"point_std_{length_unit}"] = _fmt(block.point_std * fl)
    return tags


def _builtin_like(g: ArtifactGeometry) -> bool:
    if g.kind == "custom":
        return False
    try:
        ref = ArtifactGeometry.builtin(g.kind, g.length, g.distances[0].std,
                                       g.perpendiculars[0].std if g.perpendiculars else 0.0)
    except KincalError:
        return False
    return ref == g


def write_artifact(blocks: Sequence[ArtifactMeasurement], path: str | Path,
                   units: Mapping[str, str] | None = None, robot: Any = None) -> None:
    """Write one artifact block as CSV (atomically); a custom geometry goes to a YAML beside it.

    ``units``: ``{"length": "mm", "angle": "deg"}`` (default SI).
    """
    if len(blocks) != 1:
        raise MeasurementFileError(f"an artifact file holds one block; got {len(blocks)}")
    b = blocks[0]
    u = dict(units or {})
    lu, au = u.get("length", "m"), u.get("angle", "rad")
    for unit, dim in ((lu, "length"), (au, "angle")):
        if unit not in UNITS or UNITS[unit][0] != dim:
            raise MeasurementFileError(f"unknown {dim} unit {unit!r}")
    gfile = None
    if not _builtin_like(b.geometry):
        if str(path) == "-":
            raise MeasurementFileError("a custom artifact's geometry goes to a YAML beside "
                                       "the CSV: write to a file, not stdout")
        gfile = Path(path).stem + ".geometry.yaml"
        write_geometry(b.geometry, Path(path).parent / gfile, lu, au)
    tags = artifact_tags(b, lu, au, gfile)
    cols = joint_columns(robot, b.q.shape[1], au, lu)
    lines = ["# kincal measurements: " + "; ".join(f"{k}={v}" for k, v in tags.items()),
             f"# {b.geometry.kind}: sockets {', '.join(b.geometry.sockets)}; "
             + "; ".join(f"|{d.label}| known" for d in b.geometry.distances)
             + "".join(f"; {p.a}{p.c} perpendicular to {p.b}{p.d}"
                       for p in b.geometry.perpendiculars),
             ",".join(["placement", "point"] + [c for c, _ in cols])]
    Q = b.q * np.array([f for _, f in cols])
    for pl, so, row in zip(b.placement_labels, b.socket_labels, Q, strict=True):
        lines.append(",".join([pl, so] + [_fmt(v) for v in row]))
    atomic_write_text(path, "\n".join(lines) + "\n")


# --------------------------------------------------------------------------- socket files
@dataclass(frozen=True)
class SocketData:
    """Joint readings from plain per-socket files.

    Attributes:
        q: (N, n) joint values [rad / m].
        placement: (N,) placement label of each row.
        socket: (N,) socket label of each row (the file name without extension).
    """

    q: Array
    placement: tuple[str, ...]
    socket: tuple[str, ...]


def read_socket_files(source: str | Path | Sequence[str | Path], angle_unit: str = "rad",
                      placement: str | None = None, pattern: str = "*.csv") -> SocketData:
    """Read headerless per-socket files: one file per socket, one configuration per row.

    This is the format of ``shared/data/panda_two_socket`` (MUKCa): comma-separated
    joint values without a header, ``hole_0.csv`` and ``hole_1.csv`` per placement
    folder.  Such files carry no units, so the caller states them (``angle_unit``,
    radians for that data set; every joint is taken as revolute).

    Args:
        source: a folder (all files matching ``pattern``, sorted) or a list of files.
        angle_unit: unit of the values (``rad``, ``deg`` ...).
        placement: the placement label (default: the folder's name).
        pattern: file pattern inside a folder.

    Returns:
        :class:`SocketData`; the socket of each row is its file's stem.
    """
    if angle_unit not in UNITS or UNITS[angle_unit][0] != "angle":
        raise MeasurementFileError(f"unknown angle unit {angle_unit!r}")
    if isinstance(source, str | Path) and Path(source).is_dir():
        files = sorted(Path(source).glob(pattern))
        label = placement or Path(source).name
        if not files:
            raise MeasurementFileError(f"no files matching {pattern!r}", source=str(source))
    else:
        files = [Path(source)] if isinstance(source, str | Path) else [Path(f) for f in source]
        label = placement or (files[0].parent.name if files else "")
    qs, sockets = [], []
    width = None
    for f in files:
        text = read_text(f, "socket file", MeasurementFileError)
        rows = [(k + 1, ln) for k, ln in enumerate(text.splitlines())
                if ln.strip() and not ln.lstrip().startswith("#")]
        if not rows:
            raise MeasurementFileError("line 1: no data", source=str(f))
        values: list[list[float]] = []
        for line, row in rows:
            cells = [c.strip() for c in row.split(",")]
            try:
                v = [float(c) for c in cells]
            except ValueError:
                bad = next(c for c in cells if not _is_float(c))
                raise MeasurementFileError(f"line {line}: {bad!r} is not a number (joint "
                                           "values, comma separated)", source=str(f)) from None
            if values and len(v) != len(values[0]):
                raise MeasurementFileError(f"line {line}: {len(v)} values, the rows before "
                                           f"have {len(values[0])}", source=str(f))
            if not all(np.isfinite(v)) or max(abs(x) for x in v) * UNITS[angle_unit][1] > \
                    MAX_SI:
                raise MeasurementFileError(f"line {line}: a value is not a finite joint "
                                           "value", source=str(f))
            values.append(v)
        q = np.array(values)
        if width is not None and q.shape[1] != width:
            raise MeasurementFileError(f"{q.shape[1]} joint values per row; the other files "
                                       f"have {width}", source=str(f))
        width = q.shape[1]
        qs.append(q * UNITS[angle_unit][1])
        sockets += [f.stem] * len(q)
    q = np.concatenate(qs)
    return SocketData(q, (label,) * len(q), tuple(sockets))


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True
