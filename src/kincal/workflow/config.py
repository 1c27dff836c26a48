"""Setup files: a whole calibration in one reviewable YAML file.

::

    # kincal setup file (kincal calibrate --config setup.yaml); paths relative to this file
    robot: tiago_48_schunk.urdf          # built-in name, YAML or URDF
    tip_link: wrist_ft_tool_link         # URDF only (also base_link)
    hold: {gripper_tool_mount_joint: 0deg}   # joints that never move, at this value
    data:                                # training files, each with its own reading options
      - file: train.csv
        units: {"x?": m, "y?": m, "z?": m}
        ignore: [shipped_row]
        name: mocap                      # the instrument's block name (NAME.x ...)
    validate:
      - {file: validation.csv, frames: training}
    calibration: {free: [role:offset, "mocap.*"], joint_model: [hysteresis]}
    outputs: {output: calibrated.yaml, json: result.json, report: report.html}

:func:`load_setup` reads a file, :func:`parse_setup` an already-parsed mapping (with
the folder its paths are relative to), both into a typed :class:`Setup`; errors are one
line naming the file, the line and the key (``setup.yaml: line 12: data[0].units:
...``).  :data:`CALIBRATION_KEYS` is the schema of ``calibration:`` - one key per
``kincal calibrate`` option, by its long name - and :data:`OUTPUT_KEYS` of
``outputs:``.  A fleet manifest's ``defaults:`` and sessions use the same keys; the
manifest parses each level with :func:`parse_setup` (its own line numbers) and layers the
parsed setups (:func:`kincal.fleet.manifest.layer`).

Layer rule: part of :mod:`kincal.workflow`; imports the layers below it, never the CLI.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from kincal.errors import KincalError
from kincal.io import read_text
from kincal.units import UNITS, parse_quantity
from kincal.workflow.sources import FORMATS, DataSource, detect_format, instrument_tags

__all__ = ["Setup", "YamlDocument", "SetupError", "read_yaml", "load_setup", "parse_setup",
           "hold_robot", "CALIBRATION_KEYS", "OUTPUT_KEYS", "SETUP_KEYS",
           "DATA_KEYS", "Key"]

KeyPath = tuple[str | int, ...]


class SetupError(KincalError):
    """A setup file (or fleet manifest) is malformed."""


@dataclasses.dataclass(frozen=True)
class Key:
    """One key of ``calibration:``: what its value is and how the command takes it.

    Attributes:
        kind: ``text`` (a string), ``list`` (a list or a comma-separated string; given
            to the command comma-joined), ``int``, ``float``, ``bool``, ``choice``
            (one of ``choices``), ``quantity`` (a number with a unit of ``dimension``,
            kept as text for the command), ``path`` (relative to the setup file),
            ``prior`` (``default``, ``none``, ``PATTERN=SIGMA,...`` or a mapping
            ``{pattern: sigma}``).
        help: one line for ``kincal init`` and the docs.
    """

    kind: str
    help: str = ""
    choices: tuple[str, ...] = ()
    dimension: str = ""


def _calibration_keys() -> dict[str, Key]:
    from kincal.workflow.options import LOSSES, METHODS, PROCEDURES, STAGES

    return {
        "free": Key("list", "parameters to estimate: names, * patterns, role:offset"),
        "fix": Key("list", "parameters held at their nominal values"),
        "prior": Key("prior", "Gaussian priors: {pattern: sigma or [length, angle]}, "
                              "e.g. {'*.origin.*': [1mm, 0.1deg]}"),
        "joint_model": Key("list", "non-geometric joint terms: hysteresis, compliance"),
        "stages": Key("list", f"solver stages ({', '.join(STAGES)})"),
        "procedure": Key("choice", "one-stage least squares or the staged-selection procedure's",
                         tuple(PROCEDURES)),
        "method": Key("choice", "Levenberg-Marquardt or Gauss-Newton", tuple(METHODS)),
        "loss": Key("choice", "robust loss", tuple(LOSSES)),
        "loss_scale": Key("float", "robust threshold in standard deviations"),
        "max_iter": Key("int", "iterations"),
        "cross_validate": Key("int", "K-fold cross-validation on the training file"),
        "select": Key("choice", "choose the joint model and prior scale by cross-validation "
                                "on the training files", ("auto", "none")),
        "folds": Key("int", "folds of select: auto"),
        "split": Key("choice", "what a fold of select: auto holds out (files, placements or "
                               "workspace regions; or random rows)", ("auto", "random")),
        "shared_marker": Key("bool", "the data files see one tool point: estimate it once"),
        "validation_frames": Key("choice", "instrument frames on held-out files",
                                 ("auto", "training", "register")),
        "condition_growth": Key("float", "staged-selection: data selection factor"),
        "cycles": Key("int", "staged-selection: passes through the two stages"),
        "tolerance": Key("quantity", "staged-selection: stop when no point moves more than this",
                         dimension="length"),
        "truth": Key("path", "simulations: the true robot file"),
        "all": Key("bool", "list every parameter, not only the estimated ones"),
        "force": Key("bool", "write the calibrated robot even when it cannot be trusted"),
    }


#: The schema of ``calibration:`` (one key per ``kincal calibrate`` option).
CALIBRATION_KEYS: dict[str, Key] = _calibration_keys()

#: The keys of ``outputs:`` (``kincal calibrate``'s output options by long name).
OUTPUT_KEYS: dict[str, str] = {
    "output": "the calibrated robot (YAML)",
    "urdf": "the calibrated robot as URDF",
    "json": "the result JSON",
    "report": "the HTML report",
}

#: Top-level keys of a setup file.
SETUP_KEYS = ("robot", "base_link", "tip_link", "hold", "data", "validate", "calibration",
              "outputs")

#: Keys of one ``data:`` / ``validate:`` entry.
DATA_KEYS = ("file", "units", "ignore", "instrument", "name", "format", "options", "joint_names",
             "columns", "frames")


# --------------------------------------------------------------------------- YAML with lines
@dataclasses.dataclass(frozen=True)
class YamlDocument:
    """A parsed YAML file and the line of every key and list item.

    Attributes:
        data: the parsed value (``yaml.safe_load``).
        source: the file, for messages.
        lines: ``{key path: line}`` (1-based), ``("data", 0, "units")`` -> 12.
    """

    data: Any
    source: str
    lines: Mapping[KeyPath, int]

    def line(self, path: KeyPath) -> int | None:
        """The line of ``path``, or of its nearest ancestor that has one."""
        p = tuple(path)
        while p:
            if p in self.lines:
                return self.lines[p]
            p = p[:-1]
        return self.lines.get((), None)


def read_yaml(path: str | os.PathLike[str], what: str = "setup file") -> YamlDocument:
    """Read a YAML file keeping the line of every key (for ``file: line N: key`` errors).

    Aliases are followed once (a YAML "billion laughs" costs nothing); a file that is
    not UTF-8 text, not YAML, or not there is one :class:`SetupError` line.
    """
    import yaml

    src = str(path)
    text = read_text(path, what, SetupError)
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text) if node is not None else None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise SetupError(f"{where}not valid YAML ({problem})", source=src) from None
    except RecursionError:
        raise SetupError("nested too deeply to be a setup file", source=src) from None
    except ValueError as exc:            # a scalar YAML types but cannot build (2026-13-01)
        raise SetupError(f"{_bad_scalar_line(node)}not valid YAML ({exc})", source=src
                         ) from None
    lines: dict[KeyPath, int] = {}
    if node is not None:
        lines[()] = node.start_mark.line + 1
        _walk(node, (), lines, set())
    return YamlDocument(data, src, lines)


def _bad_scalar_line(node: Any) -> str:
    """``"line N: "`` of the first scalar that YAML types but cannot construct."""
    import yaml

    stack = [node]
    while stack:
        n = stack.pop(0)
        if isinstance(n, yaml.ScalarNode):
            try:
                yaml.SafeLoader("").construct_object(n)
            except ValueError:
                return f"line {n.start_mark.line + 1}: {n.value!r}: "
        elif isinstance(n, yaml.MappingNode):
            stack += [x for kv in n.value for x in kv]
        elif isinstance(n, yaml.SequenceNode):
            stack += list(n.value)
    return ""


def _walk(node: Any, path: KeyPath, lines: dict[KeyPath, int], seen: set[int]) -> None:
    import yaml

    if id(node) in seen:                 # an alias: its lines are those of its anchor
        return
    seen.add(id(node))
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            key = k.value if isinstance(k, yaml.ScalarNode) else str(k.start_mark.line)
            lines.setdefault(path + (key,), k.start_mark.line + 1)
            _walk(v, path + (key,), lines, seen)
    elif isinstance(node, yaml.SequenceNode):
        for i, v in enumerate(node.value):
            lines.setdefault(path + (i,), v.start_mark.line + 1)
            _walk(v, path + (i,), lines, seen)


# --------------------------------------------------------------------------- the setup
@dataclasses.dataclass(frozen=True)
class Setup:
    """A calibration set-up, checked, with paths resolved against ``base_dir``.

    Attributes:
        robot: a built-in name or a path (None when the file leaves it to the command line).
        base_link, tip_link: URDF chain ends.
        hold: ``{joint: (value, dimension)}`` of joints that never move: the value in SI
            [rad / m], the dimension of its unit (None for a bare 0); apply it with
            :func:`hold_robot`.
        data, validate: training and held-out :class:`~kincal.workflow.sources.DataSource`.
        calibration: ``{key: value}`` of :data:`CALIBRATION_KEYS`, each in the form the
            ``kincal calibrate`` option takes (lists comma-joined, quantities as text).
        outputs: ``{key: path}`` of :data:`OUTPUT_KEYS`.
        source: the setup file (None for a mapping without one).
        base_dir: the folder relative paths are resolved against.
        lines: ``{key path: line}`` for messages (see :meth:`where`).
    """

    robot: str | None = None
    base_link: str | None = None
    tip_link: str | None = None
    hold: Mapping[str, tuple[float, str | None]] = dataclasses.field(default_factory=dict)
    data: tuple[DataSource, ...] = ()
    validate: tuple[DataSource, ...] = ()
    calibration: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    outputs: Mapping[str, str] = dataclasses.field(default_factory=dict)
    source: str | None = None
    base_dir: Path = Path(".")
    lines: Mapping[KeyPath, int] = dataclasses.field(default_factory=dict)

    def where(self, *path: str | int) -> str:
        """``"setup.yaml: line 4: hold.tool_joint"`` for messages about a key."""
        return _where(self.source, self.lines, tuple(path))


def _fmt_path(path: KeyPath) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def _where(source: str | None, lines: Mapping[KeyPath, int], path: KeyPath) -> str:
    p = tuple(path)
    line = None
    while True:
        if p in lines:
            line = lines[p]
            break
        if not p:
            break
        p = p[:-1]
    parts = [source] if source else []
    if line is not None:
        parts.append(f"line {line}")
    if path:
        parts.append(_fmt_path(path))
    return ": ".join(parts) or "setup"


class _Reader:
    """Typed access to the setup mapping with ``file: line N: key: ...`` errors."""

    def __init__(self, source: str | None, lines: Mapping[KeyPath, int], prefix: KeyPath,
                 base_dir: Path) -> None:
        self.source, self.lines, self.prefix, self.base_dir = source, lines, prefix, base_dir

    def fail(self, path: KeyPath, what: str) -> SetupError:
        return SetupError(f"{_where(self.source, self.lines, self.prefix + path)}: {what}")

    def mapping(self, value: Any, path: KeyPath) -> Mapping[str, Any]:
        if value is None:
            return {}
        if not isinstance(value, Mapping):
            raise self.fail(path, f"must be a mapping (key: value), got {_kind(value)}")
        for k in value:
            if not isinstance(k, str):
                raise self.fail(path, f"key {k!r} must be text")
        return value

    def keys(self, m: Mapping[str, Any], path: KeyPath, allowed: Sequence[str],
             what: str) -> None:
        for k in m:
            if k not in allowed:
                close = difflib.get_close_matches(k, list(allowed), n=1)
                hint = f"did you mean {close[0]!r}?" if close else \
                    f"{what} keys are {', '.join(allowed)}"
                raise self.fail(path + (k,), f"unknown key ({hint})")

    def text(self, value: Any, path: KeyPath) -> str:
        if isinstance(value, bool) or not isinstance(value, str | int | float) or \
                not str(value).strip():
            raise self.fail(path, f"must be text, got {_kind(value)}")
        return str(value).strip()

    def text_list(self, value: Any, path: KeyPath) -> list[str]:
        if isinstance(value, str):
            items = [s.strip() for s in value.split(",")]
        elif isinstance(value, list):
            items = [self.text(v, path + (i,)) for i, v in enumerate(value)]
        else:
            raise self.fail(path, f"must be a list or comma-separated text, got {_kind(value)}")
        items = [s for s in items if s]
        if not items:
            raise self.fail(path, "is empty")
        return items

    def integer(self, value: Any, path: KeyPath) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.fail(path, f"must be a whole number, got {_kind(value)}")
        return int(value)

    def number(self, value: Any, path: KeyPath) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(path, f"must be a number, got {_kind(value)}")
        try:
            v = float(value)
        except OverflowError:
            raise self.fail(path, "is too large") from None
        if not math.isfinite(v):
            raise self.fail(path, f"must be finite, got {value!r}")
        return v

    def boolean(self, value: Any, path: KeyPath) -> bool:
        if not isinstance(value, bool):
            raise self.fail(path, f"must be true or false, got {_kind(value)}")
        return value

    def path(self, value: Any, path: KeyPath, must_exist: bool = True) -> str:
        text = self.text(value, path)
        p = Path(text).expanduser()
        full = p if p.is_absolute() else self.base_dir / p
        if must_exist and not full.exists():
            raise self.fail(path, f"no such file {text!r}" + (
                f" (relative to {self.base_dir})" if not p.is_absolute() else ""))
        return os.path.normpath(str(full))

    def quantity(self, value: Any, path: KeyPath, dimension: str, bare_zero: bool = True
                 ) -> float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            if bare_zero and value == 0:
                return 0.0
            raise self.fail(path, f"{value!r} needs its unit (e.g. {value}"
                                  f"{'deg' if dimension == 'angle' else 'mm'})")
        try:
            return parse_quantity(self.text(value, path), dimension.split("|"),
                                  _fmt_path(path))
        except SetupError:
            raise
        except KincalError as exc:
            raise self.fail(path, str(exc).removeprefix(f"option {_fmt_path(path)}: ")
                            ) from None


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return f"{str(value).lower()}"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    return repr(value)


def _robot(r: _Reader, value: Any, path: KeyPath) -> str:
    from kincal.robots.files import library_names

    text = r.text(value, path)
    p = Path(text).expanduser()
    full = p if p.is_absolute() else r.base_dir / p
    if full.exists():
        return os.path.normpath(str(full))
    if text in library_names():
        return text
    if p.suffix.lower() in (".yaml", ".yml", ".urdf") or "/" in text:
        raise r.fail(path, f"no such robot file {text!r}" + (
            f" (relative to {r.base_dir})" if not p.is_absolute() else ""))
    close = difflib.get_close_matches(text, library_names(), n=1)
    hint = f"; did you mean {close[0]!r}?" if close else " (see `kincal robots`)"
    raise r.fail(path, f"{text!r} is neither a file nor a built-in robot{hint}")


def _hold(r: _Reader, value: Any, path: KeyPath) -> dict[str, tuple[float, str | None]]:
    from kincal.units import split_value

    m = r.mapping(value, path)
    out: dict[str, tuple[float, str | None]] = {}
    for joint, v in m.items():
        si = r.quantity(v, path + (joint,), "length|angle")
        unit = split_value(str(v), joint)[1] if isinstance(v, str) else None
        out[joint] = (si, None if unit is None else UNITS[unit][0])
    return out


def hold_robot(robot: Any, setup: Setup) -> Any:
    """``robot`` with the setup's held joints fixed (:func:`kincal.robots.hold.hold_joints`);
    a value of the wrong dimension or an unknown joint names the line."""
    from kincal.robots.chain import Robot
    from kincal.robots.hold import hold_joints

    if not setup.hold:
        return robot
    if not isinstance(robot, Robot):
        raise SetupError(f"{setup.where('hold')}: only serial robots have joints to hold")
    kinds = {j.name: j.kind for j in robot.joints}
    values = {}
    for joint, (v, dim) in setup.hold.items():
        want = "angle" if kinds.get(joint) == "revolute" else "length"
        if joint in kinds and dim is not None and dim != want:
            raise SetupError(f"{setup.where('hold', joint)}: {joint} is a "
                             f"{kinds[joint]} joint: give {'an' if want == 'angle' else 'a'} "
                             f"{want}")
        values[joint] = v
    try:
        return hold_joints(robot, values, setup.where("hold"))
    except SetupError:
        raise
    except KincalError as exc:
        raise SetupError(str(exc)) from None


def _sources(r: _Reader, value: Any, path: KeyPath, held_out: bool) -> tuple[DataSource, ...]:
    if value is None:
        return ()
    items = value if isinstance(value, list) else [value]
    if not isinstance(value, list | str | Mapping):
        raise r.fail(path, f"must be a list of files, got {_kind(value)}")
    out = []
    for i, item in enumerate(items):
        p = path + (i,) if isinstance(value, list) else path
        if isinstance(item, str):
            item = {"file": item}
        m = r.mapping(item, p)
        allowed = DATA_KEYS if held_out else tuple(k for k in DATA_KEYS if k != "frames")
        r.keys(m, p, allowed, "validate" if held_out else "data")
        if "file" not in m:
            raise r.fail(p, "needs 'file:'")
        file = r.path(m["file"], p + ("file",))
        units = {}
        for k, u in r.mapping(m.get("units"), p + ("units",)).items():
            u = r.text(u, p + ("units", k))
            if u not in UNITS:
                raise r.fail(p + ("units", k), f"unknown unit {u!r} (units: "
                                               f"{', '.join(UNITS)})")
            units[k] = u
        ignore = tuple(r.text_list(m["ignore"], p + ("ignore",))) if "ignore" in m else ()
        fmt = r.text(m.get("format", detect_format(file)), p + ("format",))
        if fmt not in FORMATS:
            raise r.fail(p + ("format",), f"{fmt!r} is not {' or '.join(FORMATS)}")
        if fmt == "mukca" and not Path(file).is_dir():
            raise r.fail(p + ("file",), "format mukca reads a folder of per-socket files")
        if fmt == "kincal" and Path(file).is_dir():
            raise r.fail(p + ("file",), "is a folder: give a file, or format: mukca for a "
                                        "folder of per-socket files")
        instrument = r.text(m["instrument"], p + ("instrument",)) if "instrument" in m \
            else None
        if instrument is not None:
            from kincal.measure.registry import instruments

            known = instruments()
            if instrument not in known:
                close = difflib.get_close_matches(instrument, list(known), n=1)
                hint = f"did you mean {close[0]!r}?" if close else \
                    f"instruments: {', '.join(sorted(known))}"
                raise r.fail(p + ("instrument",), f"unknown instrument {instrument!r} "
                                                  f"({hint})")
        name = r.text(m["name"], p + ("name",)) if "name" in m else None
        opts = r.mapping(m.get("options"), p + ("options",))
        try:
            tags = instrument_tags(opts)
        except KincalError as exc:
            raise r.fail(p + ("options",), str(exc)) from None
        tags.update(_column_maps(r, m, p, fmt))
        frames = None
        if "frames" in m:
            frames = r.text(m["frames"], p + ("frames",))
            if frames not in ("training", "register", "auto"):
                raise r.fail(p + ("frames",), f"{frames!r} is not training, register or auto")
        out.append(DataSource(file, units, ignore, instrument, name, fmt, tags, frames,
                              _where(r.source, r.lines, r.prefix + p)))
    return tuple(out)


def _column_maps(r: _Reader, m: Mapping[str, Any], p: KeyPath, fmt: str) -> dict[str, str]:
    """``joint_names:`` / ``columns:`` maps ``{file column: name}`` as tag text
    (:mod:`kincal.measure.columns`)."""
    from kincal.measure.columns import format_map

    out: dict[str, str] = {}
    for key in ("joint_names", "columns"):
        if key in m and fmt != "kincal":
            raise r.fail(p + (key,), "maps the columns of a CSV file; this source has none")
        if key == "joint_names" and isinstance(m.get(key), str) and m[key].strip() == "ros":
            out[key] = "ros"
        elif key in m:
            mp = r.mapping(m[key], p + (key,))
            try:
                out[key] = format_map({str(k): r.text(v, p + (key, k)) for k, v in mp.items()})
            except KincalError as exc:
                raise r.fail(p + (key,), str(exc)) from None
    return out


def _calibration(r: _Reader, value: Any, path: KeyPath) -> dict[str, Any]:
    m = r.mapping(value, path)
    r.keys(m, path, list(CALIBRATION_KEYS), "calibration")
    out: dict[str, Any] = {}
    for k, v in m.items():
        key, p = CALIBRATION_KEYS[k], path + (k,)
        if v is None:
            continue
        if key.kind == "list":
            out[k] = ",".join(r.text_list(v, p))
        elif key.kind == "text":
            out[k] = r.text(v, p)
        elif key.kind == "int":
            out[k] = r.integer(v, p)
        elif key.kind == "float":
            out[k] = r.number(v, p)
        elif key.kind == "bool":
            out[k] = r.boolean(v, p)
        elif key.kind == "path":
            out[k] = r.path(v, p)
        elif key.kind == "choice":
            t = r.text(v, p)
            if t not in key.choices:
                raise r.fail(p, f"{t!r} is not {', '.join(key.choices[:-1])} or "
                                f"{key.choices[-1]}")
            out[k] = t
        elif key.kind == "quantity":
            r.quantity(v, p, key.dimension, bare_zero=False)
            out[k] = r.text(v, p)
        elif key.kind == "prior":
            if isinstance(v, Mapping):
                parts = []
                for pat, sigmas in r.mapping(v, p).items():
                    many = isinstance(sigmas, list)
                    for i, sigma in enumerate(sigmas if many else [sigmas]):
                        q = p + (pat, i) if many else p + (pat,)
                        r.quantity(sigma, q, "length|angle", bare_zero=False)
                        parts.append(f"{pat}={r.text(sigma, q)}")
                out[k] = ",".join(parts)
            else:
                out[k] = r.text(v, p)
        else:                                                   # pragma: no cover
            raise r.fail(p, f"unknown kind {key.kind!r}")
    return out


def _outputs(r: _Reader, value: Any, path: KeyPath) -> dict[str, str]:
    m = r.mapping(value, path)
    r.keys(m, path, list(OUTPUT_KEYS), "outputs")
    return {k: r.path(v, path + (k,), must_exist=False) for k, v in m.items() if v is not None}


def parse_setup(mapping: Any, base_dir: str | os.PathLike[str] = ".", *,
                source: str | None = None, lines: Mapping[KeyPath, int] | None = None,
                prefix: KeyPath = (), extra_keys: Sequence[str] = ()) -> Setup:
    """Check a parsed setup mapping and resolve its paths against ``base_dir``.

    Args:
        mapping: the parsed YAML (``yaml.safe_load``) of a setup file, or of a fleet
            manifest's ``defaults:`` merged with one session.
        base_dir: the folder relative paths are relative to (the file's folder).
        source: the file, for messages.
        lines: ``{key path: line}`` from :func:`read_yaml` (for line numbers).
        prefix: where ``mapping`` sits in that file (``("robots", 3, "sessions", 0)``), so
            messages name the full key.
        extra_keys: further top-level keys the caller reads itself (a manifest's
            ``serial``, ``date``); they are not checked here.

    Returns the typed :class:`Setup`.  Raises one :class:`SetupError` line naming the
    file, line and key.
    """
    r = _Reader(source, dict(lines or {}), tuple(prefix), Path(base_dir))
    m = r.mapping(mapping, ())
    r.keys(m, (), list(SETUP_KEYS) + list(extra_keys), "setup file")
    robot = _robot(r, m["robot"], ("robot",)) if m.get("robot") is not None else None
    links = {k: r.text(m[k], (k,)) for k in ("base_link", "tip_link") if m.get(k) is not None}
    return Setup(robot=robot, base_link=links.get("base_link"),
                 tip_link=links.get("tip_link"), hold=_hold(r, m.get("hold"), ("hold",)),
                 data=_sources(r, m.get("data"), ("data",), False),
                 validate=_sources(r, m.get("validate"), ("validate",), True),
                 calibration=_calibration(r, m.get("calibration"), ("calibration",)),
                 outputs=_outputs(r, m.get("outputs"), ("outputs",)),
                 source=source, base_dir=Path(base_dir), lines=dict(lines or {}))


def load_setup(path: str | os.PathLike[str]) -> Setup:
    """Read and check a setup file (paths relative to its folder)."""
    doc = read_yaml(path)
    if doc.data is None:
        raise SetupError("line 1: the setup file is empty", source=doc.source)
    return parse_setup(doc.data, Path(path).parent, source=doc.source, lines=doc.lines)

