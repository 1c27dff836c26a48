"""The fleet's unit of work: one robot session in, one result record out.

:class:`SessionTask` holds everything one calibration needs (robot, files, options)
as plain values, so it travels to any Dask worker; :func:`calibrate_session` runs
exactly what ``kincal calibrate`` runs (:func:`~kincal.workflow.session.read_session`,
then :func:`~kincal.workflow.flow.run_flow`) and returns a plain ``dict`` record.  It
never raises for a robot's own problem: a bad file gives a record with ``status =
"failed"`` and the one-line reason, so one robot never stops the fleet.

:func:`crosscheck_session` measures the previous calibration of a robot on the new
session's data (instrument frame re-registered), the third drift indicator.

:func:`fingerprint` identifies a session's inputs: SHA-256 over the robot (its file's
bytes, or the built-in name and its library file), every data and held-out file's bytes
and the options; a re-run skips sessions whose fingerprint is already stored.

Records are SI (m, rad).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
import json
import os
import socket
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from kincal._version import __version__
from kincal.errors import KincalError
from kincal.robots.chain import ROLES

__all__ = ["SessionTask", "calibrate_session", "crosscheck_session", "fingerprint",
           "failure_record", "FLOW_OPTIONS", "READ_OPTIONS", "flow_kwargs", "task_of_record"]

#: Options of one calibration that :func:`kincal.workflow.flow.run_flow` takes (every
#: keyword of its signature but the data and the progress callback).
FLOW_OPTIONS: tuple[str, ...] = ()
#: Options of reading the session (:func:`kincal.workflow.session.read_session`).
READ_OPTIONS = ("joint_model", "base_link", "tip_link")


def _flow_options() -> tuple[str, ...]:
    from kincal.workflow.flow import run_flow

    skip = {"robot", "blocks", "holdouts", "progress"}
    return tuple(p for p in inspect.signature(run_flow).parameters if p not in skip)


FLOW_OPTIONS = _flow_options()


@dataclasses.dataclass(frozen=True)
class SessionTask:
    """One robot session to calibrate.

    Attributes:
        serial: the robot's serial number.
        date: the session date, ISO ``YYYY-MM-DD``.
        robot: a built-in robot name or an absolute path to a YAML / URDF file.
        data, validate: the training and held-out files: absolute paths or
            :class:`~kincal.workflow.sources.DataSource` (a file with its reading options).
        options: the setup file's ``calibration:`` values by long name, in the form the
            ``kincal calibrate`` option takes (``free``, ``prior``, ``joint_model``,
            ``cross_validate``, ``stages`` ...), and ``base_link``, ``tip_link``, ``hold``.
        fleet: the fleet's name.
        fingerprint: :func:`fingerprint` of the inputs (filled in by the manifest).
        source: where the session was declared, for messages (``fleet.yaml: line 12``).
        error: a problem found in the manifest for this session alone (a missing file):
            the task fails with this line instead of running.
    """

    serial: str
    date: str
    robot: str
    data: tuple[Any, ...]
    validate: tuple[Any, ...] = ()
    options: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    fleet: str = ""
    fingerprint: str = ""
    source: str = ""
    error: str | None = None

    @property
    def label(self) -> str:
        return f"{self.serial} {self.date}"


# --------------------------------------------------------------------------- fingerprint
def _robot_bytes(spec: str) -> bytes:
    path = Path(spec)
    if path.is_file():
        return path.read_bytes()
    from kincal.robots.files import library_dir

    for ext in (".yaml", ".urdf"):
        lib = library_dir() / f"{spec}{ext}"
        if lib.is_file():
            return spec.encode() + b"\0" + lib.read_bytes()
    return spec.encode()


def fingerprint(task: SessionTask) -> str:
    """SHA-256 (hex) of the robot, the files' bytes (in order, training then held-out) and
    the options (as sorted JSON).  A missing file counts by its name (the task will fail
    and say so).  The kincal version is stored beside it, not hashed: upgrading kincal
    does not recompute a fleet unless ``--force``."""
    h = hashlib.sha256()
    h.update(b"robot\0" + _robot_bytes(task.robot))
    for kind, files in (("data", task.data), ("validate", task.validate)):
        for f in map(source_of, files):
            how = {k: v for k, v in dataclasses.asdict(f).items() if k not in ("path", "where")}
            h.update(f"\0{kind}\0{Path(f.path).name}\0{json.dumps(how, sort_keys=True)}\0"
                     .encode())
            path = Path(f.path)
            for part in sorted(path.rglob("*")) if path.is_dir() else [path]:
                try:
                    h.update(part.name.encode() + b"\0" + part.read_bytes())
                except OSError:
                    h.update(b"<missing>")
    h.update(b"\0options\0" + json.dumps(dict(task.options), sort_keys=True,
                                         default=str).encode())
    h.update(b"\0error\0" + (task.error or "").encode())
    return h.hexdigest()


def source_of(item: Any) -> Any:
    """A :class:`~kincal.workflow.sources.DataSource` for a path, a source or its dict."""
    from kincal.workflow.sources import DataSource

    if isinstance(item, DataSource):
        return item
    if isinstance(item, Mapping):
        d = dict(item)
        d["ignore"] = tuple(d.get("ignore") or ())
        return DataSource(**d)
    return DataSource(str(item))


# --------------------------------------------------------------------------- options
def flow_kwargs(options: Mapping[str, Any]) -> dict[str, Any]:
    """The :func:`~kincal.workflow.flow.run_flow` keywords of ``options`` (lists given in
    a manifest become the comma-separated text the command line takes)."""
    from kincal.units import parse_quantity
    from kincal.workflow.options import parse_prior_text, parse_stages

    out: dict[str, Any] = {}
    for k, v in options.items():
        if k not in FLOW_OPTIONS:
            continue
        if isinstance(v, list | tuple):
            v = ",".join(map(str, v))
        if k == "stages":
            v = parse_stages(v)
        elif k == "tolerance" and isinstance(v, str):
            v = parse_quantity(v, "length", "tolerance")
        elif k == "prior" and isinstance(v, str):
            v = parse_prior_text(v, "prior")
        out[k] = v
    return out


def _read_kwargs(options: Mapping[str, Any]) -> dict[str, Any]:
    out = {k: options[k] for k in READ_OPTIONS if options.get(k) is not None}
    if isinstance(out.get("joint_model"), list | tuple):
        out["joint_model"] = ",".join(out["joint_model"])
    return out


# --------------------------------------------------------------------------- records
def _base_record(task: SessionTask) -> dict[str, Any]:
    return {"fleet": task.fleet, "serial": task.serial, "date": task.date,
            "fingerprint": task.fingerprint or fingerprint(task),
            "kincal_version": __version__, "robot": task.robot,
            "options": dict(task.options), "data": [_source_dict(f) for f in task.data],
            "validate": [_source_dict(f) for f in task.validate],
            "worker": f"{socket.gethostname()}:{os.getpid()}"}


def _source_dict(item: Any) -> dict[str, Any]:
    d = dataclasses.asdict(source_of(item))
    d["ignore"] = list(d["ignore"])
    return d


def failure_record(task: SessionTask, reason: str) -> dict[str, Any]:
    """The record of a session that could not be calibrated (``status = "failed"``)."""
    return {**_base_record(task), "status": "failed", "reason": reason.replace("\n", " "),
            "converged": False, "warnings": [], "parameters": [], "estimated": [],
            "covariance": np.zeros((0, 0)), "metrics": {}, "seconds": None}


def calibrate_session(task: SessionTask) -> dict[str, Any]:
    """Calibrate one robot session as ``kincal calibrate`` would; return its record.

    Record keys: ``fleet, serial, date, fingerprint, kincal_version, robot, options,
    data, validate, worker``; ``status`` (``ok``; ``not converged`` or ``untrusted``:
    the checks ``kincal calibrate`` applies, :attr:`FlowResult.trusted`; ``failed``) and
    ``reason`` (one line; None when ok); ``converged, iterations, sigma0, seconds``;
    ``parameters`` (``CalibrationResult.to_dict()["parameters"]``: name, unit, role,
    nominal, estimate, std, identifiable, estimated), ``estimated`` and ``covariance``
    (p x p over ``estimated``, SI); ``metrics`` (``train``, ``validation``,
    ``cross_validation`` as in the result JSON); ``warnings``.  The calibrated robot is
    the nominal one with the estimates (:func:`calibrated_robot`).
    """
    t0 = time.perf_counter()
    if task.error:
        return failure_record(task, task.error)
    try:
        return _calibrate(task, t0)
    except KincalError as exc:
        return failure_record(task, str(exc))
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        return failure_record(task, f"calibration failed: {type(exc).__name__}: {exc}")


def _file_stamp(spec: str) -> tuple[int, int] | None:
    p = Path(spec)
    if p.is_file():
        st = p.stat()
        return st.st_mtime_ns, st.st_size
    return None


@functools.lru_cache(maxsize=32)
def _cached_robot(spec: str, base_link: str | None, tip_link: str | None,
                  stamp: tuple[int, int] | None) -> Any:
    from kincal.workflow.robots import load_any_robot

    return load_any_robot(spec, base_link=base_link, tip_link=tip_link)


def load_robot_cached(spec: str, options: Mapping[str, Any]) -> Any:
    """The session's robot, parsed once per worker process and robot file version (robots
    are immutable values; a fleet of one model would otherwise parse the same YAML or
    URDF for every session)."""
    return _cached_robot(spec, options.get("base_link"), options.get("tip_link"),
                         _file_stamp(spec))


def _robot_of(task: SessionTask) -> Any:
    """The session's nominal robot: parsed once per process, joints held as the setup says."""
    from kincal.workflow.config import Setup, hold_robot

    robot = load_robot_cached(task.robot, _read_kwargs(task.options))
    if task.options.get("hold"):
        hold = {j: (float(v[0]), v[1]) for j, v in task.options["hold"].items()}
        robot = hold_robot(robot, Setup(hold=hold, source=task.source or None))
    return robot


def _read(task: SessionTask, validate: bool = True) -> Any:
    from kincal.workflow.session import read_session

    kw = _read_kwargs(task.options)
    robot = _robot_of(task)
    return read_session(robot, [source_of(f) for f in task.data],
                        [source_of(f) for f in task.validate] if validate else [],
                        spec=task.robot, **kw)


def _calibrate(task: SessionTask, t0: float) -> dict[str, Any]:
    from kincal.report.metrics import result_json
    from kincal.workflow.flow import run_flow

    if not task.data:
        raise KincalError("no measurement files in this session")
    session = _read(task)
    if not hasattr(session.robot, "param_names") or type(session.robot).__name__ == "FiveBar":
        raise KincalError("fleet calibration works on serial robots")
    flow = run_flow(session.robot, session.blocks, session.holdouts,
                    **flow_kwargs(task.options))
    res = flow.result
    doc = result_json(res, flow.comparisons)
    metrics = dict(doc["metrics"])
    if flow.cross_validation is not None:
        metrics["cross_validation"] = dict(flow.cross_validation)
    return {**_base_record(task),
            "status": "ok" if flow.trusted else "not converged" if not res.converged
            else "untrusted",
            "reason": None if flow.trusted else (flow.verdict.line() if flow.verdict
                                                  is not None else res.message),
            "converged": bool(res.converged), "iterations": int(res.iterations),
            "sigma0": float(res.sigma0), "seconds": time.perf_counter() - t0,
            "parameters": doc["parameters"], "estimated": list(res.estimated),
            "covariance": np.asarray(res.covariance, dtype=float),
            "metrics": metrics, "warnings": list(flow.warnings)}


def task_of_record(record: Mapping[str, Any]) -> SessionTask:
    """The :class:`SessionTask` a stored record was computed from."""
    return SessionTask(serial=record["serial"], date=record["date"], robot=record["robot"],
                       data=tuple(record.get("data") or ()),
                       validate=tuple(record.get("validate") or ()),
                       options=dict(record.get("options") or {}),
                       fleet=record.get("fleet") or "",
                       fingerprint=record.get("fingerprint") or "")


def crosscheck_session(task: SessionTask, previous: Mapping[str, float]) -> dict[str, Any]:
    """Errors of the previous calibration on this session's training data.

    Args:
        task: the new session.
        previous: ``{robot parameter: value}`` of the previous calibration (others stay
            nominal).

    The instrument frame is re-registered to the previous robot on the new data (the
    instrument moved between sessions), so what remains is what the robot changed.
    Returns ``{"status": "ok", "metrics": error_metrics}`` or ``{"status": "failed",
    "reason": ...}``.
    """
    from kincal.report.metrics import error_metrics, merge_errors
    from kincal.workflow.flow import validate_blocks

    try:
        session = _read(task, validate=False)
        r = session.robot
        values = [float(previous.get(n, v)) for n, v in zip(r.param_names, r.param_values,
                                                             strict=True)]
        comps = validate_blocks(r.with_params(np.array(values)), session.blocks)
        return {"status": "ok", "metrics": error_metrics(merge_errors([c.after
                                                                       for c in comps]))}
    except KincalError as exc:
        return {"status": "failed", "reason": str(exc)}
    except (ArithmeticError, ValueError, np.linalg.LinAlgError) as exc:
        return {"status": "failed", "reason": f"{type(exc).__name__}: {exc}"}


def calibrated_robot(record: Mapping[str, Any]) -> Any:
    """The calibrated robot of a record: its nominal robot with every robot parameter's
    estimate (the robot file ``kincal calibrate -o`` writes)."""
    nominal = _robot_of(task_of_record(record))
    est = {p["name"]: p["estimate"] for p in record["parameters"]}
    return nominal.with_params(np.array([est.get(n, v) for n, v in zip(
        nominal.param_names, nominal.param_values, strict=True)]))


def robot_parameter_names(record: Mapping[str, Any]) -> list[str]:
    """The record's robot parameters (not the instruments' blocks)."""
    return [p["name"] for p in record.get("parameters", ()) if p["role"] in ROLES]


def summary_rms(metrics: Mapping[str, Any] | None, kind: str = "position_m"
                ) -> float | None:
    """``rms_<kind>`` of a metrics entry, else its first ``rms_*`` value, else None."""
    if not metrics:
        return None
    if f"rms_{kind}" in metrics:
        return float(metrics[f"rms_{kind}"])
    for k, v in metrics.items():
        if k.startswith("rms_") and isinstance(v, int | float):
            return float(v)
    return None
