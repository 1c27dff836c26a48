"""The calibration history on a PostgreSQL server, started by the test.

The server comes from the ``pgserver`` wheel (PostgreSQL binaries inside a PyPI
package, installed by the ``test`` extra); the test skips, saying why, where that wheel
does not exist (Windows, Python >= 3.13).  The same commands as with SQLite run
against the server's URL: calibrate, re-run (skips), drift, history, export.
"""

from __future__ import annotations

import shutil
import tempfile

import pytest
from cli_helpers import run

pytest.importorskip("sqlalchemy", reason="the fleet extra (SQLAlchemy) is not installed")
pytest.importorskip("psycopg", reason="psycopg (PostgreSQL driver) is not installed: "
                    "pip install -e '.[test]'")
pgserver = pytest.importorskip("pgserver", reason="no PostgreSQL server wheel (pgserver) "
                               "for this platform / Python")

from kincal.fleet.simulate import simulate_fleet  # noqa: E402
from kincal.fleet.store import HistoryStore  # noqa: E402


@pytest.fixture(scope="module")
def postgres_url():
    """A fresh server on a data folder of its own (as root, pgserver runs the server as a
    'pgserver' system user and opens the folders above the data folder to it, so the
    data folder is not put inside pytest's private temporary folder)."""
    data = tempfile.mkdtemp(prefix="kincal-pg-")
    server, errors = None, []
    for _ in range(3):      # pgserver gives pg_ctl 10 s; a loaded machine may need a retry,
        try:                # which finds the server that was still starting
            server = pgserver.get_server(data, cleanup_mode="stop")
            break
        except Exception as exc:               # noqa: BLE001 - reported in the skip
            errors.append(f"{type(exc).__name__}: {exc}")
    if server is None:
        shutil.rmtree(data, ignore_errors=True)
        pytest.skip(f"the PostgreSQL server of pgserver did not start here: {errors}")
    uri = server.get_uri()
    yield uri.replace("postgresql://", "postgresql+psycopg://", 1)
    server.cleanup()
    shutil.rmtree(data, ignore_errors=True)


def _flat(text: str) -> str:
    return " ".join(text.split())


def test_fleet_history_on_postgresql(postgres_url, tmp_path, capsys):
    fleet = simulate_fleet(tmp_path / "fleet", robots=3, poses=30, drifted=1, broken=1,
                           seed=2)
    code, out, err = run(capsys, "fleet", "calibrate", fleet.manifest, "--db", postgres_url,
                         "--serial", "--quiet")
    assert code == 1 and "1 failed" in _flat(out), err
    assert "5 session(s) calibrated" in _flat(out)
    code, out, _ = run(capsys, "fleet", "calibrate", fleet.manifest, "--db", postgres_url,
                       "--serial", "--quiet")
    assert "5 already in the history (skipped)" in _flat(out)
    with HistoryStore(postgres_url, create=False) as store:
        rows = store.summaries()
        full = store.records([r["id"] for r in rows])
    assert len(rows) == 6 and sum(r["status"] == "ok" for r in rows) == 5
    assert all(r["covariance"].shape == (len(r["estimated"]),) * 2 for r in full)
    drifted = next(r["serial"] for r in fleet.robots if r["drift"])
    code, out, _ = run(capsys, "fleet", "drift", "--db", postgres_url)
    assert code == 1 and drifted in out
    code, out, _ = run(capsys, "fleet", "export", "--db", postgres_url, "-o",
                       tmp_path / "h.csv")
    assert code == 0 and len((tmp_path / "h.csv").read_text().splitlines()) == 7
