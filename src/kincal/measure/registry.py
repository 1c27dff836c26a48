"""Registry of instruments, so the CLI treats every measurement technology alike.

An instrument module registers an :class:`Instrument` describing how to simulate
it, how to write and read its CSV files, and its command-line options.  The
``kincal simulate`` and ``kincal calibrate`` commands look instruments up here by
name (``position``, ``pose``, ``range``, ``bearing``, ``camera``, ``plane``,
``fixture``, ``cross-bar``, ``ball-bar``, ``two-socket`` ...).

Measurement CSV files start with one comment line naming their instrument::

    # kincal measurements: instrument=position; name=tracker

followed by a header whose columns carry units (``q1_deg``, ``x_mm``); see
:mod:`kincal.measure.files` for the format.  The reader of that instrument is
chosen from that line.  A file *without* the line (a file exported by another
tool) is read as

* ``pose`` when its columns include ``x y z rx ry rz`` (any unit suffixes),
* ``position`` when they include ``x y z`` or numbered markers ``x1 y1 z1 ...``
  and no orientation columns,

and is otherwise an error asking for the tag line or ``instrument=`` (never a guess).
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from kincal.errors import MeasurementFileError
from kincal.measure.files import tag_overrides

if TYPE_CHECKING:
    from kincal.measure.base import MeasurementModel

#: kincal's own modules that register instruments when imported.  An error in one of
#: them is a bug and raises.
INSTRUMENT_MODULES: tuple[str, ...] = (
    "kincal.measure.instruments.position",
    "kincal.measure.instruments.pose",
    "kincal.measure.instruments.range",
    "kincal.measure.instruments.bearing",
    "kincal.measure.instruments.camera",
    "kincal.measure.instruments.plane",
    "kincal.measure.instruments.fixture",
    "kincal.measure.artifacts",
)

#: Entry-point group of third-party instrument plug-ins: each entry point names a
#: module (or a callable of no arguments) that calls :func:`register`.
ENTRY_POINT_GROUP = "kincal.instruments"


#: ``simulate(true_robot, rng, n_poses, noise, **options) -> (blocks, truth)``.
#:
#: ``blocks`` are measured on ``true_robot`` (a :class:`~kincal.robots.chain.Robot`) at
#: ``n_poses`` postures drawn with ``rng`` (a ``numpy.random.Generator``), with the
#: instrument's main standard deviation ``noise`` (SI: see ``noise_unit``); ``truth`` is
#: the ``{parameter name: true value}`` of the instrument's own parameters.  The keyword
#: options are the instrument's declared ``options`` (checked against them before the
#: call), plus ``truth=`` (a previous ``truth``: measure again with the same placement)
#: when ``same_placement``.  Typed as a callable of any keywords because each
#: instrument declares its own.
Simulator = Callable[..., tuple[Sequence["MeasurementModel"], Mapping[str, float]]]


class Writer(Protocol):
    """``write(blocks, path, units, robot=None)``: the CSV, written atomically.

    ``units`` is ``{"length": "m"|"mm"|..., "angle": "rad"|"deg"|...}``; ``robot``
    names the joint columns as its joints (None: ``q1 q2 ...``).
    """

    def __call__(self, blocks: Sequence[Any], path: str | Path, units: dict[str, str], /,
                 *, robot: Any = None) -> None: ...


class Reader(Protocol):
    """``read(path, robot, units, ignore=(), name=None) -> blocks``.

    ``units`` maps a column (or a ``*`` pattern) to its unit when the header has none,
    ``ignore`` lists columns to drop on purpose, ``name`` overrides the block name.
    """

    def __call__(self, path: str | Path, robot: Any, units: dict[str, str], /, *,
                 ignore: Sequence[str] = (), name: str | None = None
                 ) -> list[Any]: ...


class InstrumentPlugin(Protocol):
    """What the registry needs of a measurement technology (:class:`Instrument` is the
    ready-made implementation): its name (the ``--instrument`` value and the CSV tag
    ``instrument=NAME``), a one-line description, the SI unit of its main noise
    (``"m"``, ``"rad"`` or ``"px"``), its simulator options ``{name: (default, help)}``,
    whether its simulator takes ``truth=`` (:class:`Simulator`), and the three
    functions."""

    @property
    def name(self) -> str: ...

    @property
    def description(self) -> str: ...

    @property
    def noise_unit(self) -> str: ...

    @property
    def options(self) -> Mapping[str, tuple[Any, str]]: ...

    @property
    def same_placement(self) -> bool: ...

    @property
    def simulate(self) -> Simulator: ...

    @property
    def write(self) -> Writer: ...

    @property
    def read(self) -> Reader: ...


@dataclass(frozen=True)
class Instrument:
    """How one measurement technology is simulated, stored and read
    (:class:`InstrumentPlugin`).

    Attributes:
        name: the ``--instrument`` value and the CSV header tag.
        description: one line for ``--help`` and tables.
        simulate: the simulator (:class:`Simulator`).
        write: the CSV writer (:class:`Writer`).
        read: the CSV reader (:class:`Reader`).
        options: extra keyword options ``{name: (default, help)}`` for ``simulate``.
        noise_unit: SI unit of ``noise``: ``"m"``, ``"rad"`` or ``"px"``.
        same_placement: ``simulate`` takes ``truth=`` (a previous ``truth`` dict) to
            measure again with the same instrument placement (held-out data); False:
            every simulation places the instrument anew.
    """

    name: str
    description: str
    simulate: Simulator
    write: Writer
    read: Reader
    options: dict[str, tuple[Any, str]] = field(default_factory=dict)
    noise_unit: str = "m"
    same_placement: bool = True


_REGISTRY: dict[str, InstrumentPlugin] = {}
_loaded = False
#: Third-party plug-ins (entry points) that failed to load: ``{entry point: "Error: msg"}``,
#: listed by ``kincal instruments`` and in the unknown-instrument error.
LOAD_ERRORS: dict[str, str] = {}


def register(instrument: InstrumentPlugin) -> InstrumentPlugin:
    """Add (or replace) an instrument in the registry."""
    _REGISTRY[instrument.name] = instrument
    return instrument


def _load_all() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for mod in INSTRUMENT_MODULES:              # kincal's own: an error is a bug, raise it
        importlib.import_module(mod)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            loaded = ep.load()
            if callable(loaded):
                loaded()
        except Exception as exc:  # a broken third-party plug-in must not take kincal down
            LOAD_ERRORS[f"{ep.name} ({ep.value})"] = f"{type(exc).__name__}: {exc}"


def instruments() -> dict[str, InstrumentPlugin]:
    """All registered instruments by name."""
    _load_all()
    return dict(_REGISTRY)


def get_instrument(name: str) -> InstrumentPlugin:
    """The instrument called ``name``, or a one-line error listing the known ones."""
    known = instruments()
    if name not in known:
        broken = "".join(f"; plug-in {m} failed to load ({e})" for m, e in LOAD_ERRORS.items())
        raise MeasurementFileError(f"unknown instrument {name!r}; known: "
                                   f"{', '.join(sorted(known))}{broken}")
    return known[name]


# --------------------------------------------------------------------------- detection
def header_tag(path: str | Path) -> dict[str, str]:
    """Parse the ``# kincal measurements: instrument=...; name=...`` first line.

    Raises a one-line error when the line is missing; see :func:`detect_instrument`
    for files without it.
    """
    from kincal.measure.files import read_header

    tags, _, _ = read_header(path)
    if not tags:
        raise MeasurementFileError("line 1: expected '# kincal measurements: "
                                   "instrument=NAME' (which instrument measured this file?)",
                                   source=str(path))
    if "instrument" not in tags:
        raise MeasurementFileError("line 1: missing 'instrument=NAME'", source=str(path))
    return tags


def detect_instrument(path: str | Path, ignore: Sequence[str] = ()) -> str:
    """The instrument of a measurement file: its tag, or ``pose``/``position`` from columns.

    Raises:
        MeasurementFileError: no tag and the columns are not unambiguously position or
            pose columns.
    """
    from kincal.measure.files import glob_regex, has_tag_line, read_header, split_unit

    tags, names, line = read_header(path)
    drop = [glob_regex(p) for p in ignore]
    names = [n for n in names if not any(rx.match(n) for rx in drop)]
    if "instrument" in tags:
        return tags["instrument"]
    if has_tag_line(path):
        raise MeasurementFileError("line 1: missing 'instrument=NAME'", source=str(path))
    bases = {split_unit(n)[0] for n in names}
    has_xyz = {"x", "y", "z"} <= bases
    markers = {b for b in bases if re.fullmatch(r"[xyz]\d+", b)}
    has_rpy = {"rx", "ry", "rz"} <= bases
    any_rot = bool({b for b in bases if re.fullmatch(r"r[xyz]\d*", b)})
    if has_xyz and has_rpy and not markers:
        return "pose"
    if (has_xyz or markers) and not any_rot and not (has_xyz and markers):
        return "position"
    raise MeasurementFileError(
        f"line 1: no '# kincal measurements: instrument=NAME' line, and the header (line "
        f"{line}) is not unambiguously position (x,y,z or x1,y1,z1,...) or pose "
        "(x,y,z,rx,ry,rz) columns; add the tag line", source=str(path))


def read_measurements(path: str | Path, robot: Any, units: dict[str, str] | None = None,
                      ignore: Sequence[str] = (), name: str | None = None,
                      instrument: str | None = None,
                      tags: Mapping[str, str] | None = None) -> list[Any]:
    """Read any measurement CSV, dispatching on its instrument.

    Args:
        path: the CSV file.
        robot: the robot whose joints the file's joint columns name.
        units: ``{column or pattern: unit}`` for header columns without a unit.
        ignore: columns (or ``*`` patterns) to drop on purpose.
        name: block name to use instead of the file's ``name=`` tag.
        instrument: the instrument when the file has no tag line (a tag wins; a
            different tag is an error).
        tags: tag-line entries that override the file's (``{"instrument": "two-socket",
            "length_mm": "50"}``): how a setup file describes a file it cannot edit.

    Returns:
        The measurement blocks (usually one).
    """
    if tags:
        with tag_overrides(path, tags):
            return read_measurements(path, robot, units, ignore, name, instrument)
    detected = None
    try:
        detected = detect_instrument(path, ignore)
    except MeasurementFileError:
        if instrument is None:
            raise
    if instrument is not None and detected is not None:
        from kincal.measure.files import read_header

        tags, _, _ = read_header(path)
        if tags.get("instrument") not in (None, instrument):
            raise MeasurementFileError(f"line 1: the file says instrument="
                                       f"{tags['instrument']}, not {instrument}",
                                       source=str(path))
    inst = get_instrument(instrument or detected or "")
    return inst.read(path, robot, dict(units or {}), ignore=tuple(ignore), name=name)


def write_measurements(instrument: str | InstrumentPlugin, blocks: Sequence[Any],
                       path: str | Path, units: dict[str, str] | None = None,
                       robot: Any = None) -> None:
    """Write blocks with an instrument's writer (joint columns named after ``robot``'s
    joints when given)."""
    inst = get_instrument(instrument) if isinstance(instrument, str) else instrument
    inst.write(blocks, path, dict(units or {"length": "m", "angle": "rad"}), robot=robot)


def simulate_measurements(instrument: str | InstrumentPlugin, true_robot: Any, rng: Any,
                          n_poses: int, noise: float, options: dict[str, Any] | None = None,
                          truth: dict[str, float] | None = None
                          ) -> tuple[list[Any], dict[str, float]]:
    """Run an instrument's simulator; ``truth`` reuses a previous placement when supported.

    Returns ``(blocks, truth)``.  When the instrument cannot reuse a placement
    (``same_placement`` False) the new data has its own placement (the caller should
    then register it anew).
    """
    inst = get_instrument(instrument) if isinstance(instrument, str) else instrument
    opts = dict(options or {})
    unknown = sorted(set(opts) - set(inst.options))
    if unknown:
        raise MeasurementFileError(f"instrument {inst.name!r} has no option {unknown[0]!r} "
                                   f"(options: {', '.join(inst.options) or 'none'})")
    if truth is not None and inst.same_placement:
        opts["truth"] = truth
    blocks, true_values = inst.simulate(true_robot, rng, int(n_poses), float(noise), **opts)
    return list(blocks), dict(true_values)
