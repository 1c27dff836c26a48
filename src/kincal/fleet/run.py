"""A fleet run: tasks onto the engine, records into the history as they arrive.

:func:`calibrate_fleet`

1. skips the sessions whose inputs (serial, date, fingerprint) already have a finished
   record (``force=True`` recomputes them);
2. runs :func:`~kincal.fleet.tasks.calibrate_session` for the others on the engine and
   stores each record in its own transaction the moment it arrives (a task whose
   worker died for good is stored as failed, with the reason);
3. measures, for every robot with two calibrated session dates, the previous
   calibration on the latest session's data
   (:func:`~kincal.fleet.tasks.crosscheck_session`), where not already stored.

Nothing here prints: ``on_record`` / ``on_start`` callbacks feed a progress bar.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from kincal.fleet.engine import describe_failure
from kincal.fleet.store import HistoryStore, latest_pairs
from kincal.fleet.tasks import (
    SessionTask,
    calibrate_session,
    crosscheck_session,
    failure_record,
    fingerprint,
    robot_parameter_names,
    task_of_record,
)

__all__ = ["FleetSummary", "calibrate_fleet", "run_crosschecks"]


@dataclasses.dataclass
class FleetSummary:
    """What a fleet run did.

    Attributes:
        sessions: sessions in the manifest.
        skipped: sessions already in the history with the same inputs.
        calibrated: records stored by this run (``ok`` ones).
        failed: ``(serial, date, status, reason)`` of every session this run could not
            calibrate (``failed`` or ``not converged``).
        crosschecks: previous-calibration checks stored by this run.
        seconds: wall time [s].
        engine: the engine's description.
    """

    sessions: int = 0
    skipped: int = 0
    calibrated: int = 0
    failed: list[tuple[str, str, str, str]] = dataclasses.field(default_factory=list)
    crosschecks: int = 0
    seconds: float = 0.0
    engine: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"sessions": self.sessions, "skipped": self.skipped,
                "calibrated": self.calibrated, "crosschecks": self.crosschecks,
                "seconds": self.seconds, "engine": self.engine,
                "failed": [{"serial": s, "date": d, "status": st, "reason": r}
                           for s, d, st, r in self.failed]}


def calibrate_fleet(tasks: Sequence[SessionTask], store: HistoryStore, engine: Any, *,
                    force: bool = False,
                    on_start: Callable[[int], None] | None = None,
                    on_record: Callable[[Mapping[str, Any]], None] | None = None,
                    crosscheck: bool = True) -> FleetSummary:
    """Calibrate every session not yet in ``store``; store each record as it arrives.

    Args:
        tasks: the sessions (with fingerprints; missing ones are computed here).
        store: the history.
        engine: :class:`~kincal.fleet.engine.SerialEngine` or
            :class:`~kincal.fleet.engine.DaskEngine`.
        force: recompute sessions already stored with the same inputs.
        on_start: called once with the number of tasks to run.
        on_record: called with each stored record (progress).
        crosscheck: also run :func:`run_crosschecks` afterwards.
    """
    t0 = time.perf_counter()
    tasks = [t if t.fingerprint else dataclasses.replace(t, fingerprint=fingerprint(t))
             for t in tasks]
    done = set() if force else store.finished()
    todo = [t for t in tasks if (t.serial, t.date, t.fingerprint) not in done]
    summary = FleetSummary(sessions=len(tasks), skipped=len(tasks) - len(todo),
                           engine=engine.describe())
    if on_start is not None:
        on_start(len(todo))
    for i, record, exc in engine.map_unordered(calibrate_session, todo):
        if exc is not None:
            record = failure_record(todo[i], describe_failure(exc))
        store.add(record)
        if record["status"] == "ok":
            summary.calibrated += 1
        else:
            summary.failed.append((record["serial"], record["date"], record["status"],
                                   record.get("reason") or ""))
        if on_record is not None:
            on_record(record)
    if crosscheck:
        summary.crosschecks = run_crosschecks(store, engine)
    summary.failed.sort()
    summary.seconds = time.perf_counter() - t0
    return summary


def _crosscheck(args: tuple[SessionTask, dict[str, float]]) -> dict[str, Any]:
    return crosscheck_session(*args)


def run_crosschecks(store: HistoryStore, engine: Any) -> int:
    """Store the previous calibration's errors on the latest session of every robot with
    two calibrated dates, where not stored yet; returns how many were stored."""
    have = store.crosscheck_rows()
    pairs = [(p, n) for p, n in latest_pairs(store.summaries()) if (n["id"], p["id"]) not in have]
    if not pairs:
        return 0
    full = {r["id"]: r for r in store.records([x["id"] for pair in pairs for x in pair])}
    jobs = []
    for prev, new in pairs:
        old = full[prev["id"]]
        names = set(robot_parameter_names(old))
        values = {p["name"]: p["estimate"] for p in old["parameters"] if p["name"] in names}
        jobs.append((task_of_record(full[new["id"]]), values))
    stored = 0
    for i, result, exc in engine.map_unordered(_crosscheck, jobs):
        if exc is not None:
            result = {"status": "failed", "reason": describe_failure(exc)}
        prev, new = pairs[i]
        store.add_crosscheck(new["id"], prev["id"], result)
        stored += 1
    return stored
