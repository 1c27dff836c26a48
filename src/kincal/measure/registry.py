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
import inspect
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from kincal.errors import MeasurementFileError
from kincal.measure.files import tag_overrides

#: Modules that register instruments when imported (added to as modules land).
INSTRUMENT_MODULES: list[str] = [
    "kincal.measure.standard_instruments",
    "kincal.measure.instruments",
    "kincal.measure.artifacts",
]


@dataclass(frozen=True)
class Instrument:
    """How one measurement technology is simulated, stored and read.

    Attributes:
        name: the ``--instrument`` value and the CSV header tag.
        description: one line for ``--help`` and tables.
        simulate: ``simulate(true_robot, rng, n_poses, noise, **options) -> (blocks,
            truth)`` where ``blocks`` is a list of :class:`~kincal.measure.base.MeasurementModel`
            measured on ``true_robot`` and ``truth`` a ``{parameter name: true value}`` dict
            for the instrument's own parameters; ``noise`` is the instrument's main
            standard deviation in SI units (m for lengths, rad for angles, px for pixels;
            see ``noise_unit``).  Optionally accepts ``truth=`` (a previous ``truth``
            dict) to measure again with the same instrument placement (held-out data).
        write: ``write(blocks, path, units)`` writes the CSV (atomically).  ``units`` is
            ``{"length": "m"|"mm"|..., "angle": "rad"|"deg"|...}``; optionally accepts
            ``robot=`` to name the joint columns as the robot's joints.
        read: ``read(path, robot, units) -> list[MeasurementModel]``; ``units`` maps a
            column (or a ``*`` pattern) to its unit when the header has none.  Optionally
            accepts ``ignore=`` (columns to drop) and ``name=`` (block name override).
        options: extra keyword options ``{name: (default, help)}`` for ``simulate``.
        noise_unit: SI unit of ``noise``: ``"m"``, ``"rad"`` or ``"px"``.
    """

    name: str
    description: str
    simulate: Callable[..., tuple[list[Any], dict[str, float]]]
    write: Callable[..., None]
    read: Callable[..., list[Any]]
    options: dict[str, tuple[Any, str]] = field(default_factory=dict)
    noise_unit: str = "m"


_REGISTRY: dict[str, Instrument] = {}
_loaded = False
#: Instrument modules that failed to import: ``{module: "ErrorType: message"}``.
LOAD_ERRORS: dict[str, str] = {}


def register(instrument: Instrument) -> Instrument:
    """Add (or replace) an instrument in the registry."""
    _REGISTRY[instrument.name] = instrument
    return instrument


def _load_all() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for mod in INSTRUMENT_MODULES:
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:  # a module not installed / not written yet
            if exc.name != mod:
                LOAD_ERRORS[mod] = f"{type(exc).__name__}: {exc}"
        except Exception as exc:  # a broken plug-in must not take the others down
            LOAD_ERRORS[mod] = f"{type(exc).__name__}: {exc}"


def instruments() -> dict[str, Instrument]:
    """All registered instruments by name."""
    _load_all()
    return dict(_REGISTRY)


def get_instrument(name: str) -> Instrument:
    """The instrument called ``name``, or a one-line error listing the known ones."""
    known = instruments()
    if name not in known:
        broken = "".join(f"; {m} failed to load ({e})" for m, e in LOAD_ERRORS.items())
        raise MeasurementFileError(f"unknown instrument {name!r}; known: "
                                   f"{', '.join(sorted(known))}{broken}")
    return known[name]


def accepts(fn: Callable[..., Any], keyword: str) -> bool:
    """True when ``fn`` takes the keyword argument ``keyword`` (or ``**kwargs``)."""
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.name == keyword or p.kind is inspect.Parameter.VAR_KEYWORD for p in params)


def _with_optional(fn: Callable[..., Any], args: tuple[Any, ...], optional: dict[str, Any],
                   what: str) -> Any:
    """Call ``fn(*args, **optional)`` passing only the optional keywords it accepts.

    An optional keyword with a meaningful value that ``fn`` cannot take is an error
    (``what`` names the call in the message), never silently dropped.
    """
    kwargs = {}
    for k, v in optional.items():
        if accepts(fn, k):
            kwargs[k] = v
        elif v:
            raise MeasurementFileError(f"{what} does not support {k.replace('_', '-')}")
    return fn(*args, **kwargs)


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
    return _with_optional(inst.read, (path, robot, dict(units or {})),
                          {"ignore": tuple(ignore), "name": name},
                          f"instrument {inst.name!r}'s reader")


def write_measurements(instrument: str | Instrument, blocks: list[Any], path: str | Path,
                       units: dict[str, str] | None = None, robot: Any = None) -> None:
    """Write blocks with an instrument's writer, passing ``robot`` when it accepts one."""
    inst = get_instrument(instrument) if isinstance(instrument, str) else instrument
    units = dict(units or {"length": "m", "angle": "rad"})
    if accepts(inst.write, "robot"):
        inst.write(blocks, path, units, robot=robot)
    else:
        inst.write(blocks, path, units)


def simulate_measurements(instrument: str | Instrument, true_robot: Any, rng: Any,
                          n_poses: int, noise: float, options: dict[str, Any] | None = None,
                          truth: dict[str, float] | None = None
                          ) -> tuple[list[Any], dict[str, float]]:
    """Run an instrument's simulator; ``truth`` reuses a previous placement when supported.

    Returns ``(blocks, truth)``.  When the simulator cannot take ``truth`` the new data
    has its own placement (the caller should then register it anew).
    """
    inst = get_instrument(instrument) if isinstance(instrument, str) else instrument
    opts = dict(options or {})
    unknown = sorted(set(opts) - set(inst.options))
    if unknown:
        raise MeasurementFileError(f"instrument {inst.name!r} has no option {unknown[0]!r} "
                                   f"(options: {', '.join(inst.options) or 'none'})")
    if truth is not None and accepts(inst.simulate, "truth"):
        opts["truth"] = truth
    return inst.simulate(true_robot, rng, int(n_poses), float(noise), **opts)
