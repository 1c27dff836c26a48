"""Five-bar robot files (YAML, ``kind: fivebar``): validation, reading, writing.

Layout (units explicit; lengths in ``units.length``, angles in ``units.angle``)::

    kind: fivebar
    name: fivebar_reference
    source: where the numbers come from
    units: {length: m, angle: rad}          # length: m | mm, angle: rad | deg
    links: {l1: 2.0, l2: 2.0, l3: 3.0, l4: 3.0}
    bases: {base1: {x: 1.0, y: 0.0}, base2: {x: -1.0, y: 0.0}}
    offsets: {offset1: 0.0, offset2: 0.0}   # optional, beta_i = q_i + offset_i
    assembly: -1                            # optional, +1: J3 left of J1->J2
    working_mode: "-+"                      # optional, elbow i left of B_i->J3 is +
    limits: {q1: [0.0, 1.5708], q2: [1.5708, 3.1416]}   # optional reading limits

Every problem raises :class:`RobotFileError` with one line naming the field.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from kincal.errors import RobotFileError
from kincal.io import atomic_write_text
from kincal.parallel.fivebar import FiveBar
from kincal.robots.files import (
    ANGLE_UNITS,
    LENGTH_UNITS,
    FieldReader,
    library_dir,
    read_units,
    yaml_load,
)

_TOP_KEYS = {
    "kind",
    "name",
    "source",
    "units",
    "links",
    "bases",
    "offsets",
    "assembly",
    "working_mode",
    "limits",
    "description",
}


class _Reader(FieldReader):
    """The robot-file reader, naming the file by its base name, plus five-bar helpers."""

    def __init__(self, source: str) -> None:
        super().__init__(Path(source).name if source else "robot file")

    def mapping(self, data: Any, field: str, required: bool = True) -> Mapping[str, Any]:
        if data is None and not required:
            return {}
        if not isinstance(data, Mapping):
            return_what = "is missing" if data is None else "must be a mapping"
            raise self.fail(field, return_what)
        return data

    def number_at(self, data: Mapping[str, Any], key: str, prefix: str,
                  positive: bool = False, default: float | None = None) -> float:
        """``data[key]`` as a finite float (positive if asked); ``default`` when absent."""
        field = f"{prefix}.{key}" if prefix else key
        if key not in data:
            if default is not None:
                return default
            raise self.fail(field, "is missing")
        if not positive:
            return self.number(data[key], field)
        raw = data[key]
        if isinstance(raw, bool) or not isinstance(raw, int | float):
            raise self.fail(field, "must be a positive number")
        value = self.number(raw, field)
        if value <= 0:
            raise self.fail(field, "must be a positive number")
        return value

    def unknown(self, data: Mapping[str, Any], allowed: set[str], prefix: str) -> None:
        extra = sorted(str(k) for k in data if k not in allowed)
        if extra:
            field = f"{prefix}.{extra[0]}" if prefix else extra[0]
            raise self.fail(
                field, f"is not a five-bar field (allowed: {', '.join(sorted(allowed))})"
            )


def fivebar_from_dict(data: Mapping[str, Any], source: str) -> FiveBar:
    """Validate a parsed ``kind: fivebar`` mapping and build the robot in SI units."""
    r = _Reader(source)
    data = r.mapping(data, "kind")
    if data.get("kind") != "fivebar":
        raise r.fail("kind", "must be 'fivebar'")
    r.unknown(data, _TOP_KEYS, "")
    r.unknown(r.mapping(data.get("units"), "units"), {"length", "angle"}, "units")
    ls, an = read_units(r, data)

    links = r.mapping(data.get("links"), "links")
    r.unknown(links, {"l1", "l2", "l3", "l4"}, "links")
    lengths = {k: ls * r.number_at(links, k, "links", positive=True)
               for k in ("l1", "l2", "l3", "l4")}

    base_map = r.mapping(data.get("bases"), "bases")
    r.unknown(base_map, {"base1", "base2"}, "bases")
    coords = {}
    for b in ("base1", "base2"):
        entry = r.mapping(base_map.get(b), f"bases.{b}")
        r.unknown(entry, {"x", "y"}, f"bases.{b}")
        for c in ("x", "y"):
            coords[f"{b}_{c}"] = ls * r.number_at(entry, c, f"bases.{b}")
    if coords["base1_x"] == coords["base2_x"] and coords["base1_y"] == coords["base2_y"]:
        raise r.fail("bases.base2", "must differ from bases.base1")

    off = r.mapping(data.get("offsets"), "offsets", required=False)
    r.unknown(off, {"offset1", "offset2"}, "offsets")
    offsets = {k: an * r.number_at(off, k, "offsets", default=0.0) for k in ("offset1", "offset2")}

    assembly = data.get("assembly", 1)
    if isinstance(assembly, bool) or assembly not in (1, -1):
        raise r.fail("assembly", "must be +1 or -1")
    mode = data.get("working_mode", "+-")
    if mode not in ("++", "+-", "-+", "--"):
        raise r.fail("working_mode", "must be one of '++', '+-', '-+', '--' (quoted)")
    limits = _limits(r, data.get("limits"), an)
    name = data.get("name", Path(source).stem if source else "fivebar")
    text = data.get("source", "")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise r.fail("description", "must be a string")
    if not isinstance(name, str) or not name:
        raise r.fail("name", "must be a non-empty string")
    if not isinstance(text, str):
        raise r.fail("source", "must be a string")
    return FiveBar(
        **lengths,
        **coords,
        **offsets,
        assembly=int(assembly),
        working_mode=mode,
        limits=limits,
        name=name,
        source=text,
        description=description,
    )


def _limits(r: _Reader, data: Any, scale: float
            ) -> tuple[tuple[float, float], tuple[float, float]] | None:
    if data is None:
        return None
    data = r.mapping(data, "limits")
    r.unknown(data, {"q1", "q2"}, "limits")
    out = []
    for k in ("q1", "q2"):
        pair = data.get(k)
        good = (
            isinstance(pair, list)
            and len(pair) == 2
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in pair)
            and pair[0] < pair[1]
        )
        if not good:
            raise r.fail(f"limits.{k}", "must be [min, max] with min < max")
        out.append((scale * float(pair[0]), scale * float(pair[1])))
    return (out[0], out[1])


def fivebar_to_dict(robot: FiveBar, length_unit: str = "m", angle_unit: str = "rad"
                    ) -> dict[str, Any]:
    """Mapping for a robot file, values in the requested units."""
    ls, an = 1.0 / LENGTH_UNITS[length_unit], 1.0 / ANGLE_UNITS[angle_unit]
    out: dict[str, Any] = {
        "kind": "fivebar",
        "name": robot.name,
        "source": robot.source,
        "description": robot.description,
        "units": {"length": length_unit, "angle": angle_unit},
        "links": {k: ls * getattr(robot, k) for k in ("l1", "l2", "l3", "l4")},
        "bases": {
            b: {c: ls * getattr(robot, f"{b}_{c}") for c in ("x", "y")} for b in ("base1", "base2")
        },
        "offsets": {k: an * getattr(robot, k) for k in ("offset1", "offset2")},
        "assembly": robot.assembly,
        "working_mode": robot.working_mode,
    }
    if robot.limits is not None:
        out["limits"] = {
            k: [an * v for v in pair] for k, pair in zip(("q1", "q2"), robot.limits, strict=True)
        }
    return out


def read_fivebar(path: str | Path) -> FiveBar:
    """Read and validate a five-bar YAML file."""
    path = Path(path)
    try:
        data = yaml_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise RobotFileError(f"cannot read: {exc.strerror}", source=str(path)) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        raise RobotFileError(f"{where}not valid YAML", source=path.name) from None
    return fivebar_from_dict(data, str(path))


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write text through a temporary file next to ``path``, then rename; returns the path."""
    atomic_write_text(path, text)
    return Path(path)


def write_fivebar(robot: FiveBar, path: str | Path) -> Path:
    """Write a five-bar robot file (YAML, SI units)."""
    return write_text_atomic(path, yaml.safe_dump(fivebar_to_dict(robot), sort_keys=False))


def load_fivebar(name_or_path: str | os.PathLike[str]) -> FiveBar:
    """A five-bar from a file path or a built-in robot name (``fivebar``, ``fivebar_reference``)."""
    path = Path(name_or_path)
    if not path.is_file():
        candidate = library_dir() / f"{name_or_path}.yaml"
        if not candidate.is_file():
            names = sorted(p.stem for p in library_dir().glob("fivebar*.yaml"))
            raise RobotFileError(
                f"no robot file or built-in five-bar named {str(name_or_path)!r} "
                f"(built-in: {', '.join(names)})"
            )
        path = candidate
    return read_fivebar(path)
