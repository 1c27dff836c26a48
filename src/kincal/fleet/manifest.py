"""The fleet manifest: which robot sessions to calibrate, and how.

A manifest uses the setup-file keys of ``docs/conventions.md``, read and checked by the
setup-file loader (:mod:`kincal.workflow.config`): ``defaults`` is a setup file without
``data``; each robot may override any key, and each session adds its own ``data`` /
``validate`` (and may override any key too)::

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
              - {file: R-0001/2026-06-01/tracker.csv, units: {"x?": mm}}
            validate: [R-0001/2026-06-01/holdout.csv]

Layers combine key by key (``robot``, ``base_link``, ``tip_link`` replaced; ``hold``
and ``calibration`` merged; ``data`` / ``validate`` from the session).  A folder can
stand for a manifest: ``FOLDER/<serial>/<date>/*.csv`` is one session per date folder
(ISO dates), files whose names start with ``validate`` or ``holdout`` are held out, the
others are training data; the robot and options come from a setup file (``--config``)
or ``--robot``.  A folder holding ``fleet.yaml`` is that manifest.

Errors in the manifest's structure, its ``defaults``, a serial or a date stop everything
(one line naming the file, line and key).  An error inside one session (a missing file,
a bad unit) fails that session only: its task carries the line and is stored as failed.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from kincal.errors import KincalError
from kincal.fleet.tasks import SessionTask, fingerprint
from kincal.workflow.config import Setup, SetupError, load_setup, parse_setup, read_yaml
from kincal.workflow.sources import DataSource

__all__ = ["load_manifest", "load_folder", "load_fleet", "setup_defaults", "layer"]

_TOP = ("fleet", "defaults", "robots")
_FLEET_NOT = {"outputs": "a fleet writes every result to the history database (--db); "
              "`kincal fleet export` writes files"}


def layer(base: Setup | None, over: Setup) -> Setup:
    """``over`` on ``base``: robot and chain ends replaced when given, ``hold`` and
    ``calibration`` merged key by key, ``data`` / ``validate`` replaced when given."""
    if base is None:
        return over
    return dataclasses.replace(
        over, robot=over.robot or base.robot,
        base_link=over.base_link or base.base_link, tip_link=over.tip_link or base.tip_link,
        hold={**base.hold, **over.hold}, calibration={**base.calibration, **over.calibration},
        data=over.data or base.data, validate=over.validate or base.validate)


class _Manifest:
    """The manifest file with line-numbered errors."""

    def __init__(self, path: Path) -> None:
        self.doc = read_yaml(path, "fleet manifest")
        self.path = path
        self.folder = path.parent
        self.at = Setup(source=self.doc.source, lines=self.doc.lines)

    def fail(self, path: tuple[Any, ...], message: str) -> SetupError:
        return SetupError(f"{self.at.where(*path)}: {message}")

    def setup(self, value: Any, path: tuple[Any, ...], extra: Sequence[str] = ()) -> Setup:
        if not isinstance(value, Mapping):
            raise self.fail(path, f"must be a mapping (key: value), got {type(value).__name__}")
        for key, why in _FLEET_NOT.items():
            if key in value:
                raise self.fail(path + (key,), f"not in a fleet manifest: {why}")
        return parse_setup({k: v for k, v in value.items() if k not in extra}, self.folder,
                           source=self.doc.source, lines=self.doc.lines, prefix=path,
                           extra_keys=extra)


def _date(m: _Manifest, path: tuple[Any, ...], value: Any) -> str:
    text = value.isoformat() if isinstance(value, _dt.date) else str(value)
    try:
        return _dt.date.fromisoformat(text).isoformat()
    except ValueError:
        raise m.fail(path, f"{text!r} is not a date YYYY-MM-DD") from None


def _task(serial: str, date: str, setup: Setup, fleet: str, where: str,
          error: str | None = None) -> SessionTask:
    options: dict[str, Any] = dict(setup.calibration)
    for k in ("base_link", "tip_link"):
        if getattr(setup, k):
            options[k] = getattr(setup, k)
    if setup.hold:
        options["hold"] = {j: list(v) for j, v in setup.hold.items()}
    if error is None and not setup.robot:
        error = f"{where}: no robot: give 'robot' in defaults, the robot or the session"
    if error is None and not setup.data:
        error = f"{where}: no measurement files ('data')"
    task = SessionTask(serial=serial, date=date, robot=setup.robot or "", data=setup.data,
                       validate=setup.validate, options=options, fleet=fleet, source=where,
                       error=error)
    return dataclasses.replace(task, fingerprint=fingerprint(task))


def load_manifest(path: str | Path, defaults: Setup | None = None) -> list[SessionTask]:
    """Every robot session of a manifest file, checked (see the module docstring).

    ``defaults`` (e.g. from ``--config`` / ``--robot``) sit under the file's own defaults.
    """
    m = _Manifest(Path(path))
    top = m.doc.data
    if not isinstance(top, Mapping):
        raise m.fail((), "a fleet manifest is a mapping with 'robots' (and 'fleet', "
                         "'defaults')")
    for k in top:
        if k not in _TOP:
            raise m.fail((k,), f"unknown key (fleet manifest keys are {', '.join(_TOP)})")
    fleet = str(top.get("fleet") or m.folder.resolve().name)
    base = defaults
    if top.get("defaults") is not None:
        if isinstance(top["defaults"], Mapping) and "data" in top["defaults"]:
            raise m.fail(("defaults", "data"), "defaults is a setup file without data: "
                                               "give data per session")
        base = layer(base, m.setup(top["defaults"], ("defaults",)))
    robots = top.get("robots")
    if not isinstance(robots, list) or not robots:
        raise m.fail(("robots",), "must list the robots (serial, sessions)")
    tasks: list[SessionTask] = []
    seen: dict[tuple[str, str], str] = {}
    for i, entry in enumerate(robots):
        rp: tuple[Any, ...] = ("robots", i)
        if not isinstance(entry, Mapping) or "serial" not in entry:
            raise m.fail(rp, "needs 'serial' and 'sessions'")
        serial = str(entry["serial"]).strip()
        if not serial:
            raise m.fail(rp + ("serial",), "is empty")
        robot_setup = layer(base, m.setup(entry, rp, ("serial", "sessions")))
        sessions = entry.get("sessions")
        if not isinstance(sessions, list) or not sessions:
            raise m.fail(rp + ("sessions",), "must list the robot's sessions (date, data)")
        for j, sess in enumerate(sessions):
            sp = rp + ("sessions", j)
            if not isinstance(sess, Mapping) or "date" not in sess:
                raise m.fail(sp, "needs 'date' and 'data'")
            date = _date(m, sp + ("date",), sess["date"])
            where = m.at.where(*sp)
            if (serial, date) in seen:
                raise m.fail(sp + ("date",), f"robot {serial} has two sessions on {date} "
                                             f"(the other: {seen[serial, date]})")
            seen[serial, date] = where
            try:
                setup, error = layer(robot_setup, m.setup(sess, sp, ("date",))), None
            except KincalError as exc:              # this session only
                setup, error = robot_setup, str(exc)
            tasks.append(_task(serial, date, setup, fleet, where, error))
    return tasks


# --------------------------------------------------------------------------- folder
_HELD = ("validate", "holdout")


def load_folder(folder: str | Path, defaults: Setup | None) -> list[SessionTask]:
    """Every ``<serial>/<date>/*.csv`` session under ``folder`` (see the module doc)."""
    root = Path(folder)
    if defaults is None or not defaults.robot:
        raise KincalError("a fleet folder without fleet.yaml needs the robot: --robot ROBOT "
                          "or a setup file (--config) with 'robot'", source=str(root))
    tasks = []
    for sdir in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")):
        for ddir in sorted(p for p in sdir.iterdir() if p.is_dir()):
            try:
                date = _dt.date.fromisoformat(ddir.name).isoformat()
            except ValueError:
                raise KincalError(f"folder {ddir.relative_to(root)}: {ddir.name!r} is not a "
                                  "session date YYYY-MM-DD", source=str(root)) from None
            csv = sorted(ddir.glob("*.csv"))
            data = tuple(DataSource(str(p.resolve())) for p in csv
                         if not p.name.lower().startswith(_HELD))
            held = tuple(DataSource(str(p.resolve())) for p in csv
                         if p.name.lower().startswith(_HELD))
            if not data:
                raise KincalError(f"folder {ddir.relative_to(root)} has no measurement .csv "
                                  "file", source=str(root))
            setup = dataclasses.replace(defaults, data=data, validate=held)
            tasks.append(_task(sdir.name, date, setup, root.resolve().name,
                               str(ddir.relative_to(root))))
    if not tasks:
        raise KincalError("no <serial>/<date>/*.csv sessions found", source=str(root))
    return tasks


def load_fleet(target: str | Path, defaults: Setup | None = None) -> list[SessionTask]:
    """A manifest file, a folder holding ``fleet.yaml``, or a ``<serial>/<date>`` folder."""
    p = Path(target)
    if p.is_dir():
        if (p / "fleet.yaml").is_file():
            return load_manifest(p / "fleet.yaml", defaults)
        return load_folder(p, defaults)
    if not p.exists():
        raise KincalError("no such manifest file or fleet folder", source=str(p))
    return load_manifest(p, defaults)


def setup_defaults(config: str | None = None, robot: str | None = None) -> Setup | None:
    """The fleet's defaults from ``--config`` (a setup file without data) and ``--robot``."""
    setup = None
    if config:
        setup = load_setup(config)
        if setup.data or setup.validate:
            raise SetupError(f"{setup.where('data')}: the fleet's setup file gives the "
                             "defaults; the data come from the manifest or the folders")
    if robot:
        setup = layer(setup, parse_setup({"robot": robot}, Path.cwd()))
    return setup
