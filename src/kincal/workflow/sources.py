"""Measurement sources: a file (or a socket folder) with the options to read it.

One :class:`DataSource` per ``--data`` / ``--validate`` file or per ``data:`` entry of a
setup file: where the file is, the units of its bare columns, the columns to drop, the
instrument and its options when the file's tag line does not (or cannot) say them, the
block name and the file's format:

* ``kincal`` - a kincal measurement CSV (:mod:`kincal.measure.files`);
* ``mukca`` - a folder of headerless per-socket files, one configuration per row in
  radians, as the MUKCa two-socket recorder writes them
  (:func:`~kincal.measure.artifacts.files.read_socket_folder`); a folder given as
  data is read this way.

:func:`read_sources` reads them into measurement blocks (one per file, clashing names
renamed); :func:`sources_from_options` builds them from the command line's
``--units`` / ``--ignore`` / ``--instrument`` / ``--option``.  Instrument options use
the setup file's spelling, a value with its unit (``length: 50mm``,
``probe_length: 100mm``, ``estimate_probe: true``), and become the file's tags
(``length_mm=50``, see :mod:`kincal.measure.artifacts.files`).

Layer rule: part of :mod:`kincal.workflow`; imports :mod:`kincal.measure` and below.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from kincal.errors import KincalError, MeasurementFileError
from kincal.units import UNITS, split_value

__all__ = ["DataSource", "FORMATS", "read_sources", "sources_from_options",
           "instrument_tags", "detect_format"]

#: Formats of measurement sources.
FORMATS = ("kincal", "mukca", "ros-industrial")


@dataclasses.dataclass(frozen=True)
class DataSource:
    """A measurement file and how to read it.

    Attributes:
        path: the file (or, for ``mukca``, the folder).
        units: ``{column or pattern: unit}`` for columns whose header has none.
        ignore: columns (or ``*`` / ``?`` patterns) to drop on purpose.
        instrument: the instrument, overriding the file's tag line.
        name: the block name (its parameters are ``NAME.x`` ...), overriding the tag.
        format: ``kincal`` or ``mukca`` (:data:`FORMATS`).
        tags: further tag-line entries in the file's spelling (``{"length_mm": "50"}``).
        frames: held-out files only: ``training``, ``register`` or ``auto`` (None: the
            command's ``--validation-frames``).
        where: where the source was declared, for messages (``setup.yaml: line 9``).
    """

    path: str
    units: Mapping[str, str] = dataclasses.field(default_factory=dict)
    ignore: tuple[str, ...] = ()
    instrument: str | None = None
    name: str | None = None
    format: str = "kincal"
    tags: Mapping[str, str] = dataclasses.field(default_factory=dict)
    frames: str | None = None
    where: str | None = None

    def all_tags(self) -> dict[str, str]:
        """The tag-line entries this source sets (instrument and name included)."""
        out = dict(self.tags)
        if self.instrument:
            out["instrument"] = self.instrument
        if self.name:
            out["name"] = self.name
        return out


def instrument_tags(options: Mapping[str, Any], what: str = "instrument option"
                    ) -> dict[str, str]:
    """Instrument options as tag-line entries: ``{"length": "50mm"} -> {"length_mm": "50"}``.

    A value with a unit moves its unit into the key (the tag spelling of
    :mod:`kincal.measure.artifacts.files`); booleans become ``true`` / ``false``; a key
    already ending in a unit (``length_mm: 50``) is kept as it is.
    """
    out: dict[str, str] = {}
    for key, value in options.items():
        k = str(key).strip()
        if isinstance(value, bool):
            out[k] = "true" if value else "false"
        elif isinstance(value, int | float):
            out[k] = repr(value)
        elif isinstance(value, str):
            text = value.strip()
            try:
                number, unit = split_value(text, f"{what} {k}")
            except KincalError:
                out[k] = text                      # a word: probe=tool, sockets=eliminate
                continue
            if unit is None or UNITS[unit][0] == "dimensionless":
                out[k] = repr(number)
            else:
                out[f"{k}_{unit}"] = repr(number)
        else:
            raise KincalError(f"{what} {k}: {value!r} is not a value (a number with its "
                              "unit, a word or true/false)")
    return out


def detect_format(path: str | Path) -> str:
    """``mukca`` for a folder (the one folder format), ``ros-industrial`` for a ROS-I
    observation YAML (:mod:`kincal.measure.rosi`), else ``kincal``."""
    if Path(path).is_dir():
        return "mukca"
    if Path(path).suffix.lower() in (".yaml", ".yml"):
        from kincal.measure.rosi import is_rosi_observations

        if is_rosi_observations(path):
            return "ros-industrial"
    return "kincal"


def _matching(path: str, umap: Mapping[str, str]) -> dict[str, str]:
    from kincal.measure.files import glob_regex, read_header

    if not umap:
        return {}
    names = read_header(path)[1]
    return {k: v for k, v in umap.items() if any(glob_regex(k).match(n) for n in names)}


def _matching_list(path: str, patterns: Sequence[str]) -> list[str]:
    from kincal.measure.files import glob_regex, read_header

    if not patterns:
        return []
    names = read_header(path)[1]
    return [p for p in patterns if any(glob_regex(p).match(n) for n in names)]


def sources_from_options(paths: Iterable[str], units: str | None = None,
                         ignore: Sequence[str] | None = None, instrument: str | None = None,
                         options: Mapping[str, Any] | None = None) -> list[DataSource]:
    """The command line's files as sources: every ``--units`` / ``--ignore`` entry goes to
    the files whose columns it matches (an entry matching no file is an error), and
    ``--instrument`` / ``--option`` to every file."""
    from kincal.measure.files import parse_list_option, parse_units_option
    from kincal.workflow.options import check_options_used

    paths = [str(p) for p in paths]
    umap = parse_units_option(units)
    drop = parse_list_option(ignore)
    files = [p for p in paths if detect_format(p) == "kincal"]
    for p in paths:
        if not Path(p).exists():
            raise MeasurementFileError("no such measurement file", source=p)
    if files:
        check_options_used(files, units, ignore)
    elif umap or drop:
        raise KincalError("--units / --ignore name columns, but no measurement file has "
                          "a header")
    tags = instrument_tags(options or {})
    out = []
    for p in paths:
        fmt = detect_format(p)
        if fmt == "kincal":
            out.append(DataSource(p, _matching(p, umap), tuple(_matching_list(p, drop)),
                                  instrument, None, fmt, tags))
        else:
            out.append(DataSource(p, {}, (), instrument, None, fmt, tags))
    return out


def _read_one(src: DataSource, robot: Any, name: str | None) -> list[Any]:
    from kincal.measure.registry import read_measurements

    try:
        if src.format == "mukca":
            from kincal.measure.artifacts.files import read_socket_folder

            if not Path(src.path).is_dir():
                raise MeasurementFileError("format mukca is a folder of per-socket files "
                                           "(hole_0.csv, hole_1.csv)", source=src.path)
            angle = dict(src.units).get("*", "rad")
            tags = {k: v for k, v in src.all_tags().items() if k != "name"}
            return read_socket_folder(src.path, robot, tags, name=name or src.name,
                                      angle_unit=angle)
        if src.format == "ros-industrial":
            from kincal.measure.files import tag_overrides
            from kincal.measure.rosi import read_rosi_observations

            with tag_overrides(src.path, src.all_tags()):
                return list(read_rosi_observations(src.path, robot, name=name or src.name))
        if Path(src.path).is_dir():
            raise MeasurementFileError("is a folder; a folder of per-socket files needs "
                                       "format mukca", source=src.path)
        tags = {k: v for k, v in src.all_tags().items() if k != "instrument"}
        return read_measurements(src.path, robot, dict(src.units), src.ignore,
                                 name=name or src.name, instrument=src.instrument,
                                 tags=tags or None)
    except KincalError as exc:
        if src.where and not str(exc).startswith(src.path):
            raise type(exc)(f"{src.where}: {exc}") from None
        raise


def read_sources(sources: Sequence[DataSource], robot: Any) -> list[Any]:
    """Read measurement sources, one block each (a clashing block name gets 2, 3 ...).

    Every block's ``provenance`` holds its file, its parsed table and its
    :class:`DataSource`.  Raises one-line errors for bad files.
    """
    from kincal.measure.base import Provenance

    blocks: list[Any] = []
    taken: set[str] = set()
    for src in sources:
        if src.format not in FORMATS:
            raise KincalError(f"{src.where or src.path}: format {src.format!r} is not "
                              f"{' or '.join(FORMATS)}")
        if not Path(src.path).exists():
            raise MeasurementFileError("no such measurement file", source=src.path)
        for b in _read_one(src, robot, None):
            if b.name in taken:
                k = 2
                while f"{b.name}{k}" in taken:
                    k += 1
                b = _read_one(src, robot, f"{b.name}{k}")[0]
            taken.add(b.name)
            b.provenance = Provenance(src.path, b.provenance.table if b.provenance else None,
                                      src)
            blocks.append(b)
    return blocks
