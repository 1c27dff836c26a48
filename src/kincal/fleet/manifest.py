"""The fleet manifest: which robot sessions to calibrate, and how.

A manifest uses the setup-file keys of ``docs/conventions.md``: ``defaults`` is a setup
file without ``data``; each robot may override any key, and each session adds its own
``data`` / ``validate`` (and may override any key too)::

    fleet: plant-7                      # optional name
    defaults:
      robot: puma560                    # built-in name, YAML or URDF (paths relative to
      calibration: {joint_model: [hysteresis], cross_validate: 5}   # this file)
    robots:
      - serial: R-0001
        robot: r0001.urdf               # a robot of another model
        sessions:
          - date: 2026-03-02
            data: [R-0001/2026-03-02/tracker.csv]
          - date: 2026-06-01
            data:
              - file: R-0001/2026-06-01/tracker.csv
                units: {"x?": mm}
            validate: [R-0001/2026-06-01/holdout.csv]

A folder can stand for a manifest: ``FOLDER/<serial>/<date>/*.csv`` is one session per
date folder (ISO dates), files whose names start with ``validate`` or ``holdout`` are
held out, the others are training data; the robot and options come from a setup file
(``--config``) or ``--robot``.  A folder holding ``fleet.yaml`` is that manifest.

Errors name the file, line and key (``fleet.yaml: line 12: robots[0].sessions[1].date:
...``) and stop before anything runs.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from kincal.errors import KincalError
from kincal.fleet.tasks import FLOW_OPTIONS, READ_OPTIONS, SessionTask, fingerprint

__all__ = ["load_manifest", "load_folder", "load_fleet", "CALIBRATION_KEYS", "SETUP_KEYS"]

#: Keys of ``calibration:`` (every ``kincal calibrate`` option of the flow, by long name).
CALIBRATION_KEYS = tuple(sorted(set(FLOW_OPTIONS) | {"joint_model"}))
#: Setup-file keys a manifest level may hold (``data`` / ``validate`` on sessions).
SETUP_KEYS = ("robot", "base_link", "tip_link", "calibration", "units", "ignore")
_FILE_KEYS = ("file", "units", "ignore")
_NOT_YET = {"hold": "holding joints at a value", "outputs": "per-session output files "
            "(the fleet writes its records to the history database; `kincal fleet export` "
            "writes them out)", "instrument": "overriding a file's instrument",
            "format": "other file formats", "frames": "per-file validation frames (use "
            "calibration: {validation_frames: ...})"}


# --------------------------------------------------------------------------- YAML with lines
class _Doc:
    """A YAML document as plain values, with the line of every key path."""

    def __init__(self, text: str, source: str) -> None:
        import yaml

        self.source = source
        self.lines: dict[tuple[Any, ...], int] = {}
        try:
            loader = yaml.SafeLoader(text)
            try:
                node = loader.get_single_node()
                self.value = self._build(loader, node, ()) if node is not None else None
            finally:
                loader.dispose()
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f"line {mark.line + 1}: " if mark is not None else ""
            problem = getattr(exc, "problem", None) or str(exc)
            raise KincalError(f"{where}not valid YAML ({problem})", source=source) from None

    def _build(self, loader: Any, node: Any, path: tuple[Any, ...]) -> Any:
        import yaml

        self.lines.setdefault(path, node.start_mark.line + 1)
        if isinstance(node, yaml.MappingNode):
            out: dict[str, Any] = {}
            for k, v in node.value:
                key = k.value if k.tag.endswith(":timestamp") else str(
                    loader.construct_object(k, deep=True))
                self.lines[path + (key,)] = k.start_mark.line + 1
                if key in out:
                    self.fail(path + (key,), "given twice")
                out[key] = self._build(loader, v, path + (key,))
            return out
        if isinstance(node, yaml.SequenceNode):
            return [self._build(loader, v, path + (i,)) for i, v in enumerate(node.value)]
        if node.tag.endswith(":timestamp"):
            return node.value                  # dates stay text, checked where used
        return loader.construct_object(node, deep=True)

    def line(self, path: tuple[Any, ...]) -> int:
        while path and path not in self.lines:
            path = path[:-1]
        return self.lines.get(path, 1)

    def fail(self, path: tuple[Any, ...], message: str) -> None:
        key = "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path).lstrip(".")
        raise KincalError(f"line {self.line(path)}: {key + ': ' if key else ''}{message}",
                          source=self.source)


# --------------------------------------------------------------------------- checks
def _expect(doc: _Doc, path: tuple[Any, ...], value: Any, kind: type | tuple[type, ...],
            what: str) -> Any:
    if not isinstance(value, kind) or isinstance(value, bool) and bool not in (
            kind if isinstance(kind, tuple) else (kind,)):
        doc.fail(path, f"expected {what}, got {type(value).__name__} {value!r}")
    return value


def _check_keys(doc: _Doc, path: tuple[Any, ...], value: Mapping[str, Any],
                allowed: Sequence[str]) -> None:
    for k in value:
        if k in _NOT_YET:
            doc.fail(path + (k,), f"{_NOT_YET[k]} is not supported in a fleet manifest yet")
        if k not in allowed:
            doc.fail(path + (k,), f"unknown key (allowed here: {', '.join(allowed)})")


def _calibration(doc: _Doc, path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    _expect(doc, path, value, dict, "a mapping of calibration options")
    out = {}
    for k, v in value.items():
        if k not in CALIBRATION_KEYS:
            doc.fail(path + (k,), f"unknown calibration option (known: "
                     f"{', '.join(CALIBRATION_KEYS)})")
        if k == "tolerance" and isinstance(v, str):
            v = _length(doc, path + (k,), v)
        out[k] = v
    return out


def _length(doc: _Doc, path: tuple[Any, ...], text: str) -> float:
    from kincal.units import parse_quantity

    try:
        return parse_quantity(text, "length", str(path[-1]))
    except KincalError as exc:
        doc.fail(path, str(exc))
        raise


def _merge(base: dict[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = {**out.get(k, {}), **v} if k == "calibration" else v
    return out


def _level(doc: _Doc, path: tuple[Any, ...], value: Mapping[str, Any],
           extra: Sequence[str]) -> dict[str, Any]:
    """The setup keys of one level (defaults, robot, session), checked."""
    _check_keys(doc, path, value, list(SETUP_KEYS) + list(extra))
    out: dict[str, Any] = {}
    for k in SETUP_KEYS:
        if k not in value:
            continue
        v = value[k]
        if k == "calibration":
            out[k] = _calibration(doc, path + (k,), v)
        elif k == "units":
            out[k] = dict(_expect(doc, path + (k,), v, dict, "a mapping column: unit"))
        elif k == "ignore":
            out[k] = [str(x) for x in (v if isinstance(v, list) else [v])]
        else:
            out[k] = str(_expect(doc, path + (k,), v, str, "text"))
    return out


def _files(doc: _Doc, path: tuple[Any, ...], value: Any, folder: Path,
           units: dict[str, Any], ignore: list[str]) -> list[str]:
    """Resolved paths of a ``data`` / ``validate`` list; per-file ``units`` / ``ignore``
    are merged into the session's (the same column with two units is an error)."""
    if isinstance(value, str):
        value = [value]
    _expect(doc, path, value, list, "a list of files")
    out = []
    for i, item in enumerate(value):
        p = path + (i,)
        if isinstance(item, dict):
            _check_keys(doc, p, item, _FILE_KEYS)
            if "file" not in item:
                doc.fail(p, "needs 'file'")
            for col, unit in (item.get("units") or {}).items():
                if units.get(col, unit) != unit:
                    doc.fail(p + ("units", col), f"{unit!r} here but {units[col]!r} for "
                             "another file of the session")
                units[col] = unit
            extra = item.get("ignore") or []
            ignore += [str(x) for x in (extra if isinstance(extra, list) else [extra])]
            item = item["file"]
        name = str(_expect(doc, p, item, str, "a file path"))
        f = (folder / name).resolve()
        out.append(str(f))
    return out


def _date(doc: _Doc, path: tuple[Any, ...], value: Any) -> str:
    try:
        return _dt.date.fromisoformat(str(value)).isoformat()
    except ValueError:
        doc.fail(path, f"{value!r} is not a date YYYY-MM-DD")
        raise


def _robot_spec(value: str, folder: Path) -> str:
    """A built-in name as it is; a path made absolute (relative to the manifest)."""
    if "/" in value or "\\" in value or value.lower().endswith((".yaml", ".yml", ".urdf")):
        return str((folder / value).resolve())
    return value


def _task(doc: _Doc, path: tuple[Any, ...], serial: str, date: str, setup: dict[str, Any],
          data: list[str], validate: list[str], fleet: str, folder: Path) -> SessionTask:
    if "robot" not in setup:
        doc.fail(path, "no robot: give 'robot' in defaults, the robot or the session")
    options: dict[str, Any] = dict(setup.get("calibration") or {})
    for k in READ_OPTIONS:
        if setup.get(k):
            options[k] = setup[k]
    task = SessionTask(serial=serial, date=date, robot=_robot_spec(setup["robot"], folder),
                       data=tuple(data), validate=tuple(validate), options=options,
                       fleet=fleet, source=f"{doc.source}: line {doc.line(path)}")
    return dataclasses.replace(task, fingerprint=fingerprint(task))


# --------------------------------------------------------------------------- manifest
def load_manifest(path: str | Path, defaults: Mapping[str, Any] | None = None
                  ) -> list[SessionTask]:
    """Every robot session of a manifest file, checked (one-line errors with lines).

    ``defaults`` (setup keys, e.g. from ``--robot``) sit under the file's own defaults.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise KincalError(f"cannot read the manifest ({exc.strerror or exc})",
                          source=str(path)) from None
    doc = _Doc(text, str(path))
    top = doc.value
    if not isinstance(top, dict):
        doc.fail((), "a fleet manifest is a mapping with 'robots' (and 'fleet', 'defaults')")
    _check_keys(doc, (), top, ("fleet", "defaults", "robots"))
    folder = path.parent
    fleet = str(top.get("fleet") or path.parent.name)
    base = dict(defaults or {})
    if "defaults" in top:
        base = _merge(base, _level(doc, ("defaults",), _expect(
            doc, ("defaults",), top["defaults"], dict, "a setup mapping"), ()))
    robots = top.get("robots")
    if not robots:
        doc.fail(("robots",), "the manifest lists no robots")
    _expect(doc, ("robots",), robots, list, "a list of robots")
    tasks: list[SessionTask] = []
    seen: dict[tuple[str, str], int] = {}
    for i, entry in enumerate(robots):
        rp = ("robots", i)
        _expect(doc, rp, entry, dict, "a robot (serial, sessions)")
        setup = _merge(base, _level(doc, rp, entry, ("serial", "sessions")))
        if "serial" not in entry:
            doc.fail(rp, "needs 'serial'")
        serial = str(entry["serial"]).strip()
        if not serial:
            doc.fail(rp + ("serial",), "is empty")
        sessions = entry.get("sessions")
        if not sessions:
            doc.fail(rp + ("sessions",), "lists no sessions")
        _expect(doc, rp + ("sessions",), sessions, list, "a list of sessions")
        for j, sess in enumerate(sessions):
            sp = rp + ("sessions", j)
            _expect(doc, sp, sess, dict, "a session (date, data)")
            s_setup = _merge(setup, _level(doc, sp, sess, ("date", "data", "validate")))
            if "date" not in sess:
                doc.fail(sp, "needs 'date'")
            date = _date(doc, sp + ("date",), sess["date"])
            if (serial, date) in seen:
                doc.fail(sp + ("date",), f"robot {serial} has two sessions on {date} (the "
                         f"other at line {seen[serial, date]})")
            seen[serial, date] = doc.line(sp + ("date",))
            if "data" not in sess:
                doc.fail(sp, "needs 'data' (the session's measurement files)")
            units = dict(s_setup.get("units") or {})
            ignore = list(s_setup.get("ignore") or [])
            data = _files(doc, sp + ("data",), sess["data"], folder, units, ignore)
            validate = _files(doc, sp + ("validate",), sess.get("validate") or [], folder,
                              units, ignore)
            s_setup = {**s_setup, "units": units or None, "ignore": ignore or None}
            tasks.append(_task(doc, sp, serial, date, s_setup, data, validate, fleet, folder))
    return tasks


# --------------------------------------------------------------------------- folder
_HELD = ("validate", "holdout")


def load_folder(folder: str | Path, defaults: Mapping[str, Any]) -> list[SessionTask]:
    """Every ``<serial>/<date>/*.csv`` session under ``folder`` (see the module doc)."""
    root = Path(folder)
    if "robot" not in defaults:
        raise KincalError("a fleet folder without fleet.yaml needs the robot: --robot ROBOT "
                          "or a setup file (--config) with 'robot'", source=str(root))
    doc = _Doc("{}", str(root))
    tasks = []
    for sdir in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        for ddir in sorted(p for p in sdir.iterdir() if p.is_dir()):
            try:
                date = _dt.date.fromisoformat(ddir.name).isoformat()
            except ValueError:
                raise KincalError(f"folder {ddir.relative_to(root)}: {ddir.name!r} is not a "
                                  "session date YYYY-MM-DD", source=str(root)) from None
            csv = sorted(ddir.glob("*.csv"))
            data = [str(p.resolve()) for p in csv if not p.name.lower().startswith(_HELD)]
            held = [str(p.resolve()) for p in csv if p.name.lower().startswith(_HELD)]
            if not data:
                raise KincalError(f"folder {ddir.relative_to(root)} has no measurement .csv "
                                  "file", source=str(root))
            tasks.append(_task(doc, (), sdir.name, date, dict(defaults), data, held,
                               root.resolve().name, Path.cwd()))
    if not tasks:
        raise KincalError("no <serial>/<date>/*.csv sessions found", source=str(root))
    return tasks


def load_fleet(target: str | Path, defaults: Mapping[str, Any] | None = None
               ) -> list[SessionTask]:
    """A manifest file, a folder holding ``fleet.yaml``, or a ``<serial>/<date>`` folder."""
    p = Path(target)
    if p.is_dir():
        if (p / "fleet.yaml").is_file():
            return load_manifest(p / "fleet.yaml", defaults)
        return load_folder(p, defaults or {})
    if not p.exists():
        raise KincalError("no such manifest file or fleet folder", source=str(p))
    return load_manifest(p, defaults)


def setup_defaults(path: str | Path) -> dict[str, Any]:
    """The setup keys of a setup file (``--config``) as fleet defaults (no ``data``)."""
    path = Path(path)
    try:
        doc = _Doc(path.read_text(encoding="utf-8"), str(path))
    except OSError as exc:
        raise KincalError(f"cannot read the setup file ({exc.strerror or exc})",
                          source=str(path)) from None
    _expect(doc, (), doc.value, dict, "a setup mapping")
    value = {k: v for k, v in doc.value.items() if k not in ("data", "validate")}
    out = _level(doc, (), value, ())
    if "robot" in out:
        out["robot"] = _robot_spec(out["robot"], path.parent)
    return out
