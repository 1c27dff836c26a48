"""Fleet calibration on real Dask clusters and a real SQLite file.

* one task = exactly ``kincal calibrate`` (same numbers as the command's JSON);
* an embedded ``LocalCluster`` with 2 worker processes (started once for the module)
  gives the same records as the in-process loop, stores a failed robot's one-line reason
  and skips stored sessions on a re-run (``--force`` recomputes, no duplicate rows);
* a real ``dask scheduler`` + ``dask worker`` pair (subprocesses on 127.0.0.1) through
  ``kincal fleet calibrate --scheduler``;
* faults: a worker process killed mid-run, the run itself killed and restarted, a
  corrupt, foreign, newer or locked database file.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import invoke, run

pytest.importorskip("distributed", reason="the fleet extra (dask[distributed]) is not "
                    "installed: pip install -e '.[test]'")
pytest.importorskip("sqlalchemy", reason="the fleet extra (SQLAlchemy) is not installed")

from fleet_helpers import start_scheduler_and_worker, stop  # noqa: E402

from kincal.fleet.engine import DaskEngine, SerialEngine  # noqa: E402
from kincal.fleet.manifest import load_fleet  # noqa: E402
from kincal.fleet.run import calibrate_fleet  # noqa: E402
from kincal.fleet.simulate import simulate_fleet  # noqa: E402
from kincal.fleet.store import HistoryStore  # noqa: E402
from kincal.fleet.tasks import calibrate_session  # noqa: E402

ROBOTS, POSES = 6, 30


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """6 robots x 2 sessions x 30 poses; one drifted, one with a broken last file."""
    root = tmp_path_factory.mktemp("fleet")
    return simulate_fleet(root, robots=ROBOTS, poses=POSES, drifted=1, broken=1, seed=4)


@pytest.fixture(scope="module")
def cluster():
    """A real LocalCluster with 2 worker processes, for the whole module."""
    with DaskEngine(workers=2) as engine:
        engine.start()
        yield engine


@pytest.fixture(scope="module")
def serial_records(fleet):
    """The in-process loop's records, by (serial, date): the reference."""
    return {(t.serial, t.date): calibrate_session(t) for t in load_fleet(fleet.root)}


def _flat(text: str) -> str:
    """Console text without rich's line wrapping."""
    return " ".join(text.split())


def _rows(db: Path, table: str = "calibrations") -> int:
    with sqlite3.connect(db) as c:
        return int(c.execute(f"select count(*) from {table}").fetchone()[0])


def test_a_task_runs_exactly_kincal_calibrate(fleet, tmp_path, serial_records):
    task = load_fleet(fleet.root)[0]
    out = tmp_path / "res.json"
    assert invoke("calibrate", "puma560", "--data", task.data[0].path, "--json", out) == 0
    doc = json.loads(out.read_text())
    rec = serial_records[task.serial, task.date]
    assert rec["status"] == "ok"
    assert [p["name"] for p in rec["parameters"]] == [p["name"] for p in doc["parameters"]]
    np.testing.assert_array_equal([p["estimate"] for p in rec["parameters"]],
                                  [p["estimate"] for p in doc["parameters"]])
    assert rec["metrics"]["train"]["rms_position_m"] == doc["metrics"]["train"][
        "rms_position_m"]
    est = [p for p in rec["parameters"] if p["estimated"]]
    np.testing.assert_allclose(np.sqrt(np.diag(rec["covariance"])),
                               [p["std"] for p in est], rtol=1e-12)


def test_local_cluster_matches_the_serial_loop_and_stores_failures(fleet, cluster, tmp_path,
                                                                   serial_records):
    db = tmp_path / "h.db"
    with HistoryStore(str(db)) as store:
        summary = calibrate_fleet(load_fleet(fleet.root), store, cluster)
        stored = store.records([r["id"] for r in store.summaries()])
    assert summary.sessions == 2 * ROBOTS and summary.calibrated == 2 * ROBOTS - 1
    broken = next(r for r in fleet.robots if r["broken"])
    [(serial, date, status, reason)] = summary.failed
    assert (serial, date, status) == (broken["serial"], broken["broken"]["date"], "failed")
    assert f"line {broken['broken']['line']}" in reason and "'n/a' is not a number" in reason
    assert summary.crosschecks == ROBOTS - 1
    assert len(stored) == 2 * ROBOTS
    for rec in stored:
        ref = serial_records[rec["serial"], rec["date"]]
        assert rec["status"] == ref["status"]
        if rec["status"] != "ok":
            assert rec["reason"] == ref["reason"]
            continue
        by_name = {p["name"]: p for p in rec["parameters"]}
        for p in ref["parameters"]:      # same numbers on a worker process as in this one
            assert by_name[p["name"]]["estimate"] == pytest.approx(p["estimate"], abs=1e-12)
        np.testing.assert_allclose(rec["covariance"], ref["covariance"], rtol=1e-9,
                                   atol=1e-30)
        assert rec["worker"] != ref["worker"]


def test_rerun_skips_stored_sessions_and_force_recomputes(fleet, cluster, tmp_path):
    db = tmp_path / "h.db"
    tasks = load_fleet(fleet.root)
    with HistoryStore(str(db)) as store:
        calibrate_fleet(tasks, store, SerialEngine())
        ids = {(r["serial"], r["date"]): r["id"] for r in store.summaries()}
        again = calibrate_fleet(tasks, store, cluster)
        assert again.skipped == 2 * ROBOTS - 1 and again.calibrated == 0
        assert len(again.failed) == 1              # the broken file is tried again
        assert again.crosschecks == 0
        forced = calibrate_fleet(tasks, store, cluster, force=True)
        assert forced.skipped == 0 and forced.calibrated == 2 * ROBOTS - 1
        new_ids = {(r["serial"], r["date"]): r["id"] for r in store.summaries()}
    assert _rows(db) == 2 * ROBOTS                 # replaced, not duplicated
    assert _rows(db, "crosschecks") == ROBOTS - 1
    assert set(new_ids) == set(ids) and all(new_ids[k] != ids[k] for k in ids)


def test_scheduler_option_runs_on_an_existing_cluster(fleet, tmp_path, capsys):
    address, procs = start_scheduler_and_worker(tmp_path)
    try:
        db = tmp_path / "h.db"
        code, out, err = run(capsys, "fleet", "calibrate", fleet.manifest, "--db", db,
                             "--scheduler", address, "--quiet", "--json", tmp_path / "s.json")
    finally:
        stop(procs)
    assert code == 1, err                          # the broken robot fails the run
    assert f"scheduler {address}" in _flat(out)
    assert "1 session(s) failed" in _flat(err)
    doc = json.loads((tmp_path / "s.json").read_text())
    assert doc["calibrated"] == 2 * ROBOTS - 1 and len(doc["failed"]) == 1
    assert _rows(db) == 2 * ROBOTS


def test_unreachable_scheduler_is_one_line(fleet, tmp_path, capsys):
    code, _, err = run(capsys, "fleet", "calibrate", fleet.manifest, "--db", tmp_path / "h.db",
                       "--scheduler", "tcp://127.0.0.1:9", "--quiet")
    assert code == 2 and "cannot reach a Dask scheduler" in err
    assert err.startswith("error: ") and "Traceback" not in err


def test_a_worker_killed_mid_run_loses_nothing(fleet, cluster, tmp_path):
    """SIGKILL one worker process as soon as the first record arrives: its task is re-run
    on the other worker (or reported), every session is stored exactly once."""
    killed: list[int] = []

    def kill_one(record):
        if not killed:
            pid = next(iter(cluster.worker_pids().values()))
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    db = tmp_path / "h.db"
    with HistoryStore(str(db)) as store:
        summary = calibrate_fleet(load_fleet(fleet.root), store, cluster, on_record=kill_one)
    assert killed
    assert summary.calibrated + len(summary.failed) == 2 * ROBOTS
    assert summary.calibrated == 2 * ROBOTS - 1      # the nanny restarted the worker
    assert _rows(db) == 2 * ROBOTS
    cluster.client.wait_for_workers(2, timeout=120)   # leave the module's cluster whole


def test_a_killed_run_restarts_where_it_stopped(fleet, tmp_path, capsys):
    """The run is SIGKILLed right after its third record: the restart computes only the
    rest, keeps the three rows as they were and writes no duplicate."""
    db = tmp_path / "h.db"
    script = textwrap.dedent(f"""
        import os, signal
        from kincal.fleet.engine import SerialEngine
        from kincal.fleet.manifest import load_fleet
        from kincal.fleet.run import calibrate_fleet
        from kincal.fleet.store import HistoryStore
        seen = []
        def die(record):
            seen.append(record)
            if len(seen) == 3:
                os.kill(os.getpid(), signal.SIGKILL)
        calibrate_fleet(load_fleet({str(fleet.root)!r}), HistoryStore({str(db)!r}),
                        SerialEngine(), on_record=die)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    with sqlite3.connect(db) as c:
        before = c.execute("select id, serial, session_date, created_at from calibrations "
                           "where status = 'ok' order by id").fetchall()
    assert len(before) == 3
    code, out, _ = run(capsys, "fleet", "calibrate", fleet.manifest, "--db", db, "--serial",
                       "--quiet")
    assert code == 1
    assert "3 already in the history (skipped)" in _flat(out)
    assert f"{2 * ROBOTS - 1 - 3} session(s) calibrated" in _flat(out)
    with sqlite3.connect(db) as c:
        after = c.execute("select id, serial, session_date, created_at from calibrations "
                          "where status = 'ok' order by id").fetchall()
        dupes = c.execute("select count(*) from (select serial, session_date from "
                          "calibrations group by serial, session_date having count(*) > 1)"
                          ).fetchone()[0]
    assert after[:3] == before and len(after) == 2 * ROBOTS - 1 and dupes == 0


def test_a_locked_database_is_one_line_and_nothing_runs(fleet, tmp_path, capsys):
    db = tmp_path / "h.db"
    HistoryStore(str(db)).close()
    holder = sqlite3.connect(db, isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        code, out, err = run(capsys, "fleet", "calibrate", fleet.manifest, "--db", db,
                             "--serial", "--lock-timeout", "50ms", "--quiet")
    finally:
        holder.execute("ROLLBACK")
        holder.close()
    assert code == 2
    assert _flat(err).startswith(f"error: {db}: the database is locked by another process")
    assert "calibrated" not in out
    assert _rows(db) == 0


@pytest.mark.parametrize("content, message", [
    (b"this is a CSV file, not a database\n", "not an SQLite database"),
    (b"SQLite format 3\x00" + b"\xff" * 5000, "corrupt or not an SQLite database"),
])
def test_a_corrupt_database_file_is_one_line(fleet, tmp_path, capsys, content, message):
    db = tmp_path / "h.db"
    db.write_bytes(content)
    for args in (["calibrate", fleet.manifest, "--serial", "--quiet"], ["drift"],
                 ["export", "-o", tmp_path / "x.csv"]):
        code, _, err = run(capsys, "fleet", *args, "--db", db)
        assert code == 2 and message in _flat(err), (args, err)
        assert err.startswith("error: ") and "Traceback" not in err
    assert db.read_bytes() == content and not (tmp_path / "x.csv").exists()


def test_a_foreign_or_newer_database_is_refused(tmp_path, capsys):
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as c:
        c.execute("create table invoices (id integer)")
    code, _, err = run(capsys, "fleet", "drift", "--db", other)
    assert code == 2 and "not a kincal fleet history (it has the tables invoices)" in err
    newer = tmp_path / "newer.db"
    HistoryStore(str(newer)).close()
    with sqlite3.connect(newer) as c:
        c.execute("update kincal_schema set version = 99")
    code, _, err = run(capsys, "fleet", "history", "--db", newer)
    assert code == 2 and "written by a newer kincal (schema 99" in err
    code, _, err = run(capsys, "fleet", "drift", "--db", tmp_path / "missing.db")
    assert code == 2 and "no such database file" in err


def test_export_history_and_parameters(fleet, tmp_path, capsys):
    db = tmp_path / "h.db"
    with HistoryStore(str(db)) as store:
        calibrate_fleet(load_fleet(fleet.root), store, SerialEngine())
        records = store.records([r["id"] for r in store.summaries()])
    code, out, _ = run(capsys, "fleet", "export", "--db", db, "-o", tmp_path / "h.csv",
                       "--parameters", tmp_path / "p.csv")
    assert code == 0 and f"{2 * ROBOTS} calibration record(s)" in out
    import csv

    rows = list(csv.DictReader((tmp_path / "h.csv").open()))
    assert len(rows) == 2 * ROBOTS
    ok = next(r for r in records if r["status"] == "ok")
    row = next(r for r in rows if r["id"] == str(ok["id"]))
    a2 = next(p for p in ok["parameters"] if p["name"] == "a[2]")
    assert float(row["a[2] [mm]"]) == pytest.approx(a2["estimate"] * 1e3, rel=1e-9)
    assert float(row["rms_train_mm"]) == pytest.approx(ok["rms_train_m"] * 1e3, rel=1e-5)
    params = list(csv.DictReader((tmp_path / "p.csv").open()))
    assert len(params) == sum(len(r["parameters"]) for r in records)
    assert run(capsys, "fleet", "export", "--db", db, "-o", tmp_path / "h.json")[0] == 0
    doc = json.loads((tmp_path / "h.json").read_text())
    rec = next(r for r in doc["records"] if r["id"] == ok["id"])
    np.testing.assert_allclose(rec["covariance"], ok["covariance"])
    code, _, err = run(capsys, "fleet", "export", "--db", db, "-o", tmp_path / "h.txt")
    assert code == 2 and "give a .csv or .json file name" in err


def test_exported_robot_files_are_what_kincal_calibrate_writes(fleet, tmp_path, capsys):
    db = tmp_path / "h.db"
    with HistoryStore(str(db)) as store:
        calibrate_fleet(load_fleet(fleet.root), store, SerialEngine(), crosscheck=False)
    code, out, _ = run(capsys, "fleet", "export", "--db", db, "-o", tmp_path / "h.csv",
                       "--out-dir", tmp_path / "robots")
    assert code == 0 and f"{ROBOTS} calibrated robot file(s)" in _flat(out)
    code, out, _ = run(capsys, "fleet", "export", "--db", db, "-o", tmp_path / "h2.csv",
                       "--out-dir", f"{tmp_path / 'slash'}/")     # a trailing slash
    assert code == 0 and "//" not in out
    assert sorted(p.name for p in (tmp_path / "slash").iterdir()) == \
        sorted(p.name for p in (tmp_path / "robots").iterdir())
    r = fleet.robots[0]
    latest = fleet.root / r["serial"] / r["dates"][-1] / "tracker.csv"
    assert invoke("calibrate", "puma560", "--data", latest, "-o", tmp_path / "cal.yaml") == 0
    from kincal.robots.files import load_serial_robot

    mine = load_serial_robot(tmp_path / "robots" / f"{r['serial']}.yaml")
    theirs = load_serial_robot(tmp_path / "cal.yaml")
    assert mine.param_names == theirs.param_names
    np.testing.assert_allclose(mine.param_values, theirs.param_values, rtol=0, atol=1e-12)
