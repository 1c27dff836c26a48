"""The calibration history: records in, records out, one transaction per record.

:class:`HistoryStore` opens a database by SQLAlchemy URL (``postgresql+psycopg://...``)
or by file path (SQLite: one file, no server), creates or checks the tables of
:mod:`kincal.fleet.schema`, and stores each calibration record in its own transaction,
so a run killed half-way loses nothing it had finished.  Storing a record replaces the
rows of the same inputs (serial, session date, fingerprint: no duplicates on a re-run)
and any failed record of the same session.

Every database problem becomes one line naming the database (a locked SQLite file,
a corrupt or foreign file, a schema from a newer kincal, an unreachable server):
:class:`~kincal.errors.KincalError`.
"""

from __future__ import annotations

import datetime as _dt
import functools
import json
import sqlite3
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, Concatenate, ParamSpec, TypeVar

import numpy as np
from sqlalchemy import create_engine, delete, event, insert, inspect, select, update
from sqlalchemy.engine import make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError

from kincal.errors import KincalError
from kincal.fleet.schema import (
    SCHEMA_VERSION,
    calibrations,
    crosschecks,
    metadata,
    parameters,
    schema_table,
)
from kincal.fleet.tasks import summary_rms

__all__ = ["HistoryStore", "database_url", "FINISHED"]

#: Statuses of a record that a re-run does not recompute.
FINISHED = ("ok", "not converged", "untrusted")
_SQLITE_MAGIC = b"SQLite format 3\x00"
P = ParamSpec("P")
R = TypeVar("R")


def database_url(db: str) -> str:
    """An SQLAlchemy URL for ``db``: a URL as it is, a file path as ``sqlite:///PATH``."""
    if "://" in db:
        return db
    return f"sqlite:///{Path(db).expanduser().resolve()}"


def _reason(exc: BaseException) -> str:
    orig = getattr(exc, "orig", None) or exc
    text = str(orig).splitlines()[0] if str(orig) else type(orig).__name__
    low = text.lower()
    if "locked" in low or "could not obtain lock" in low:
        return ("the database is locked by another process (another `kincal fleet` run "
                f"writing to it?); nothing was written ({text})")
    if "not a database" in low or "malformed" in low:
        return f"the database file is corrupt or not an SQLite database ({text})"
    return f"database error: {type(orig).__name__}: {text}"


def _guarded(method: Callable[Concatenate[HistoryStore, P], R]
             ) -> Callable[Concatenate[HistoryStore, P], R]:
    @functools.wraps(method)
    def wrapper(store: HistoryStore, /, *args: P.args, **kwargs: P.kwargs) -> R:
        try:
            return method(store, *args, **kwargs)
        except (SQLAlchemyError, sqlite3.Error) as exc:
            raise KincalError(_reason(exc), source=store.display) from None
    return wrapper


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _json(v: Any) -> str:
    return json.dumps(v, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


class HistoryStore:
    """A calibration history database.

    Args:
        db: an SQLAlchemy URL, or a file path (SQLite; created when missing).
        lock_timeout: seconds to wait for a locked SQLite file before giving up.
        create: create the tables of a new (empty) database; False: it must exist.
    """

    def __init__(self, db: str, lock_timeout: float = 30.0, create: bool = True) -> None:
        url = database_url(db)
        try:
            parsed = make_url(url)
        except ArgumentError:
            raise KincalError(f"--db: {db!r} is neither a file path nor a database URL"
                              ) from None
        self.display = (db if "://" not in db else
                        parsed.render_as_string(hide_password=True))
        self.sqlite = parsed.get_backend_name() == "sqlite"
        self.lock_timeout = float(lock_timeout)
        self.path = Path(parsed.database) if self.sqlite and parsed.database else None
        if self.sqlite and self.path is not None:
            self._check_sqlite_file(create)
        kwargs: dict[str, Any] = {}
        if self.sqlite:
            kwargs["connect_args"] = {"timeout": float(lock_timeout)}
        try:
            self.engine = create_engine(url, **kwargs)
        except (ArgumentError, ImportError, SQLAlchemyError) as exc:
            raise KincalError(f"cannot open the database ({type(exc).__name__}: {exc}); "
                              "a PostgreSQL URL needs a driver, e.g. pip install "
                              "'psycopg[binary]' and postgresql+psycopg://...",
                              source=self.display) from None
        if self.sqlite:
            event.listen(self.engine, "connect", _sqlite_pragmas)
        self._open(create)

    # ------------------------------------------------------------------ opening
    def _check_sqlite_file(self, create: bool) -> None:
        assert self.path is not None
        if not self.path.exists():
            if not create:
                raise KincalError("no such database file", source=self.display)
            if not self.path.parent.is_dir():
                raise KincalError("the folder of the database file does not exist",
                                  source=self.display)
            return
        if self.path.is_dir():
            raise KincalError("is a folder, not a database file", source=self.display)
        with open(self.path, "rb") as f:
            head = f.read(16)
        if head and head != _SQLITE_MAGIC:
            raise KincalError("not an SQLite database (corrupt, or another kind of file)",
                              source=self.display)

    @_guarded
    def _open(self, create: bool) -> None:
        names = set(inspect(self.engine).get_table_names())
        if schema_table.name not in names:
            ours = {t.name for t in metadata.sorted_tables}
            if names - ours:
                raise KincalError("not a kincal fleet history (it has the tables "
                                  f"{', '.join(sorted(names - ours))})", source=self.display)
            if not create:
                raise KincalError("not a kincal fleet history (no kincal_schema table)",
                                  source=self.display)
            with self.engine.begin() as c:
                metadata.create_all(c)
                c.execute(insert(schema_table).values(version=SCHEMA_VERSION))
        with self.engine.connect() as c:
            version = c.execute(select(schema_table.c.version)).scalar()
        if version is None or version > SCHEMA_VERSION:
            raise KincalError(f"written by a newer kincal (schema {version}; this kincal "
                              f"reads schema {SCHEMA_VERSION}): upgrade kincal",
                              source=self.display)

    @_guarded
    def check_writable(self) -> None:
        """Fail now, with a clear line, if another process holds the write lock."""
        if self.sqlite and self.path is not None:
            con = sqlite3.connect(str(self.path), timeout=self.lock_timeout,
                                  isolation_level=None)
            try:
                con.execute("BEGIN IMMEDIATE")
                con.execute("ROLLBACK")
            finally:
                con.close()
        else:
            with self.engine.begin() as c:
                c.execute(update(schema_table).values(version=schema_table.c.version))

    def close(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> HistoryStore:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ writing
    @_guarded
    def finished(self) -> set[tuple[str, str, str]]:
        """``(serial, session date, fingerprint)`` of every finished record."""
        c_ = calibrations.c
        with self.engine.connect() as c:
            rows = c.execute(select(c_.serial, c_.session_date, c_.fingerprint)
                             .where(c_.status.in_(FINISHED)))
            return {(r[0], r[1], r[2]) for r in rows}

    @_guarded
    def add(self, record: Mapping[str, Any]) -> int:
        """Store one record (a :func:`kincal.fleet.tasks.calibrate_session` dict) in one
        transaction; returns its id.  Replaces the rows of the same serial, date and
        fingerprint, and failed rows of the same session."""
        c_ = calibrations.c
        metrics = record.get("metrics") or {}
        cov = np.asarray(record.get("covariance", np.zeros((0, 0))), dtype="<f8")
        row = {
            "fleet": record.get("fleet") or "", "serial": record["serial"],
            "session_date": record["date"], "fingerprint": record["fingerprint"],
            "status": record["status"], "reason": record.get("reason"),
            "kincal_version": record["kincal_version"], "created_at": _now(),
            "robot": record["robot"], "options": _json(record.get("options") or {}),
            "files": _json({"data": record.get("data") or [],
                            "validate": record.get("validate") or []}),
            "converged": bool(record.get("converged")),
            "iterations": record.get("iterations"), "sigma0": record.get("sigma0"),
            "seconds": record.get("seconds"),
            "rms_train_m": summary_rms(metrics.get("train")),
            "rms_validation_m": summary_rms(metrics.get("validation")),
            "rms_cv_m": summary_rms(metrics.get("cross_validation")),
            "metrics": _json(metrics), "warnings": _json(record.get("warnings") or []),
            "estimated": _json(list(record.get("estimated") or [])),
            "covariance": cov.tobytes() if cov.size else None,
            "worker": record.get("worker"),
        }
        with self.engine.begin() as c:
            old = [r[0] for r in c.execute(select(c_.id).where(
                (c_.serial == row["serial"]) & (c_.session_date == row["session_date"])
                & ((c_.fingerprint == row["fingerprint"]) | (c_.status == "failed"))))]
            if old:
                self._delete(c, old)
            key = c.execute(insert(calibrations).values(**row)).inserted_primary_key
            assert key is not None                # a single-row insert always has its key
            new_id = int(key[0])
            params = [{"calibration_id": new_id, "name": p["name"], "unit": p["unit"],
                       "role": p["role"], "nominal": p["nominal"], "estimate": p["estimate"],
                       "std": p.get("std"), "estimated": bool(p["estimated"]),
                       "identifiable": bool(p["identifiable"])}
                      for p in record.get("parameters") or ()]
            if params:
                c.execute(insert(parameters), params)
        return new_id

    @staticmethod
    def _delete(c: Any, ids: Sequence[int]) -> None:
        x = crosschecks.c
        c.execute(delete(crosschecks).where(x.calibration_id.in_(ids) | x.previous_id.in_(ids)))
        c.execute(delete(parameters).where(parameters.c.calibration_id.in_(ids)))
        c.execute(delete(calibrations).where(calibrations.c.id.in_(ids)))

    @_guarded
    def add_crosscheck(self, calibration_id: int, previous_id: int,
                       result: Mapping[str, Any]) -> None:
        """Store the previous calibration's errors on a later session's data."""
        metrics = result.get("metrics") or {}
        with self.engine.begin() as c:
            x = crosschecks.c
            c.execute(delete(crosschecks).where((x.calibration_id == calibration_id)
                                                & (x.previous_id == previous_id)))
            c.execute(insert(crosschecks).values(
                calibration_id=calibration_id, previous_id=previous_id,
                status=result.get("status", "ok"), reason=result.get("reason"),
                rms_position_m=summary_rms(metrics), metrics=_json(metrics)))

    # ------------------------------------------------------------------ reading
    @_guarded
    def summaries(self, serials: Iterable[str] | None = None) -> list[dict[str, Any]]:
        """Every record without its parameters, oldest session first (by serial)."""
        cols = [col for col in calibrations.c if col.name != "covariance"]
        q = select(*cols).order_by(calibrations.c.serial, calibrations.c.session_date,
                                   calibrations.c.id)
        if serials is not None:
            q = q.where(calibrations.c.serial.in_(list(serials)))
        with self.engine.connect() as c:
            return [self._decode(dict(r._mapping)) for r in c.execute(q)]

    @_guarded
    def records(self, ids: Sequence[int]) -> list[dict[str, Any]]:
        """Full records (parameters, covariance) by id, in that order."""
        out: dict[int, dict[str, Any]] = {}
        with self.engine.connect() as c:
            for start in range(0, len(ids), 500):
                chunk = list(ids[start:start + 500])
                for r in c.execute(select(calibrations).where(calibrations.c.id.in_(chunk))):
                    rec = self._decode(dict(r._mapping))
                    n = len(rec["estimated"])
                    blob = rec.pop("covariance")
                    rec["covariance"] = (np.frombuffer(blob, dtype="<f8").reshape(n, n).copy()
                                         if blob else np.zeros((0, 0)))
                    rec["parameters"] = []
                    out[rec["id"]] = rec
                q = select(parameters).where(parameters.c.calibration_id.in_(chunk))
                for p in c.execute(q):
                    d = dict(p._mapping)
                    out[d.pop("calibration_id")]["parameters"].append(d)
        order = {n: i for i, n in enumerate(("base", "offset", "length", "angle", "tool"))}
        for rec in out.values():
            names = [p["name"] for p in rec["parameters"]]
            rec["parameters"].sort(key=lambda p: (order.get(p["role"], 9), names.index(p["name"])))
        return [out[i] for i in ids if i in out]

    @_guarded
    def crosscheck_rows(self) -> dict[tuple[int, int], dict[str, Any]]:
        """``{(calibration id, previous id): row}`` of every stored cross-check."""
        with self.engine.connect() as c:
            rows = [dict(r._mapping) for r in c.execute(select(crosschecks))]
        for r in rows:
            r["metrics"] = json.loads(r["metrics"])
        return {(r["calibration_id"], r["previous_id"]): r for r in rows}

    @staticmethod
    def _decode(row: dict[str, Any]) -> dict[str, Any]:
        row["date"] = row.pop("session_date")
        for key in ("options", "metrics", "warnings", "estimated"):
            if key in row:
                row[key] = json.loads(row[key]) if row[key] else ({} if key in (
                    "options", "metrics") else [])
        files = json.loads(row.pop("files")) if row.get("files") else {}
        row["data"], row["validate"] = files.get("data", []), files.get("validate", [])
        return row


def _sqlite_pragmas(dbapi_con: Any, _: Any) -> None:
    """Foreign keys on; write-ahead log with ``synchronous=NORMAL``: readers (``kincal fleet
    drift`` during a run) never wait for the writer, and a commit costs no disk flush.  A
    killed process loses no committed record (the log is in the file system); a power cut
    may lose the last few, never the file's consistency."""
    cur = dbapi_con.cursor()
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA synchronous=NORMAL")
    cur.close()


def latest_pairs(summaries: Sequence[Mapping[str, Any]]) -> list[tuple[Any, Any]]:
    """Per serial, ``(previous, latest)`` of the newest record of each session date
    among finished records (``ok``), when the robot has two dates; else nothing."""
    by_serial: dict[str, dict[str, Mapping[str, Any]]] = {}
    for s in summaries:
        if s["status"] != "ok":
            continue
        dates = by_serial.setdefault(s["serial"], {})
        if s["date"] not in dates or s["id"] > dates[s["date"]]["id"]:
            dates[s["date"]] = s
    out = []
    for serial in sorted(by_serial):
        dates = by_serial[serial]
        if len(dates) >= 2:
            d = sorted(dates)
            out.append((dates[d[-2]], dates[d[-1]]))
    return out
