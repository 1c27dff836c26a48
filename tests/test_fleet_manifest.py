"""The fleet manifest and folder layout, the simulate command, and the import rule.

Manifest errors name the file, line and key; options reach the calibration (a
manifest's ``cross_validate`` gives the same CV numbers as ``kincal calibrate
--cross-validate``); a ``<serial>/<date>/*.csv`` folder is a fleet; the command line
starts without importing Dask or SQLAlchemy.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest
from cli_helpers import invoke, run

import kincal
from kincal.errors import KincalError

pytest.importorskip("sqlalchemy", reason="the fleet extra (SQLAlchemy) is not installed")

from kincal.fleet.manifest import load_fleet, load_manifest  # noqa: E402
from kincal.fleet.simulate import simulate_fleet  # noqa: E402
from kincal.fleet.tasks import calibrate_session  # noqa: E402


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp("small")
    return simulate_fleet(root, robots=2, sessions=2, poses=30, drifted=0, broken=0, seed=9)


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("body, message", [
    ("robots:\n  - serial: A\n    sessions:\n      - {date: 2026-13-01, data: [x.csv]}\n",
     "line 4: '2026-13-01': not valid YAML (month must be in 1..12)"),
    ("robots:\n  - serial: A\n    sessions:\n      - {date: \"26-02-30\", data: [x.csv]}\n",
     "line 4: robots[0].sessions[0].date: '26-02-30' is not a date YYYY-MM-DD"),
    ("defaults:\n  robot: puma560\n  calibration:\n    fre: role:offset\nrobots: []\n",
     "line 4: defaults.calibration.fre: unknown key (did you mean 'free'?)"),
    ("defaults: {robot: puma560}\nrobots:\n  - serial: A\n    sesions: []\n",
     "line 4: robots[0].sesions: unknown key (did you mean 'sessions'?)"),
    ("defaults: {robot: puma560}\nrobots:\n  - serial: A\n    sessions:\n"
     "      - {date: 2026-01-02, data: [x.csv]}\n      - {date: 2026-01-02, data: [y.csv]}\n",
     "line 6: robots[0].sessions[1].date: robot A has two sessions on 2026-01-02 (the "
     "other: "),
    ("defaults: {robot: puma560, outputs: {json: r.json}}\nrobots: []\n",
     "line 1: defaults.outputs: not in a fleet manifest"),
    ("defaults: {robot: puma560, data: [x.csv]}\nrobots: []\n",
     "line 1: defaults.data: defaults is a setup file without data"),
    ("fleet: x\nrobot: puma560\n", "line 2: robot: unknown key (fleet manifest keys are"),
    ("robots: [\n", "not valid YAML"),
])
def test_manifest_errors_name_file_line_and_key(tmp_path, body, message):
    path = _write(tmp_path / "fleet.yaml", body)
    with pytest.raises(KincalError) as err:
        load_manifest(path)
    assert str(err.value).startswith(f"{path}: ")
    assert message in str(err.value)


def test_a_bad_session_fails_alone(small, tmp_path):
    """A missing file or a bad unit inside one session fails that session only, with its
    line; the other sessions run."""
    r = small.robots[0]
    good = small.root / r["serial"] / r["dates"][0] / "tracker.csv"
    path = _write(tmp_path / "fleet.yaml", f"""
defaults: {{robot: puma560}}
robots:
  - serial: A
    sessions:
      - {{date: 2026-01-02, data: [{good}]}}
      - {{date: 2026-02-02, data: [missing.csv]}}
      - date: 2026-03-02
        data: [{{file: {good}, units: {{x: furlong}}}}]
""")
    ok, missing, bad_unit = load_manifest(path)
    assert ok.error is None
    assert "line 7: robots[0].sessions[1].data[0].file: no such file 'missing.csv'" in \
        missing.error
    assert "line 9: robots[0].sessions[2].data[0].units.x: unknown unit 'furlong'" in \
        bad_unit.error
    assert calibrate_session(ok)["status"] == "ok"
    rec = calibrate_session(missing)
    assert rec["status"] == "failed" and rec["reason"] == missing.error


def test_manifest_options_reach_the_calibration(small, tmp_path):
    r = small.robots[0]
    data = [str(small.root / r["serial"] / d / "tracker.csv") for d in r["dates"]]
    path = _write(tmp_path / "fleet.yaml", f"""
fleet: plant-7
defaults:
  robot: puma560
  calibration: {{cross_validate: 3, stages: [offsets, all]}}
robots:
  - serial: {r['serial']}
    sessions:
      - date: {r['dates'][0]}
        data: [{data[0]}]
      - date: {r['dates'][1]}
        data:
          - file: {data[1]}
            units: {{x: mm}}
        calibration: {{free: "role:offset", cross_validate: 2}}
""")
    first, second = load_manifest(path)
    assert first.fleet == "plant-7" and first.options["cross_validate"] == 3
    assert second.options == {"cross_validate": 2, "stages": "offsets,all",
                              "free": "role:offset"}
    assert dict(second.data[0].units) == {"x": "mm"}
    assert first.fingerprint != second.fingerprint
    rec = calibrate_session(first)
    out = tmp_path / "r.json"
    assert invoke("calibrate", "puma560", "--data", data[0], "--cross-validate", "3",
                  "--stages", "offsets,all", "--json", out) == 0
    cv = json.loads(out.read_text())["metrics"]["cross_validation"]
    assert rec["metrics"]["cross_validation"] == cv
    offsets = calibrate_session(second)
    assert {p["role"] for p in offsets["parameters"] if p["estimated"]} <= {
        "offset", "instrument", "tool_point"}


def test_a_folder_of_serial_date_files_is_a_fleet(small, tmp_path, capsys):
    folder = tmp_path / "plant"
    for r in small.robots:
        for d in r["dates"]:
            target = folder / r["serial"] / d
            target.mkdir(parents=True)
            (target / "tracker.csv").write_bytes((small.root / r["serial"] / d /
                                                  "tracker.csv").read_bytes())
    with pytest.raises(KincalError, match="needs the robot"):
        load_fleet(folder)
    from kincal.fleet.manifest import setup_defaults

    tasks = load_fleet(folder, setup_defaults(robot="puma560"))
    assert [(t.serial, t.date) for t in tasks] == [(r["serial"], d) for r in small.robots
                                                   for d in r["dates"]]
    code, out, _ = run(capsys, "fleet", "calibrate", folder, "--robot", "puma560", "--db",
                       tmp_path / "h.db", "--serial", "--quiet")
    assert code == 0 and "4 session(s) calibrated" in " ".join(out.split())
    (folder / "R-00001" / "last-week").mkdir()
    code, _, err = run(capsys, "fleet", "calibrate", folder, "--robot", "puma560", "--db",
                       tmp_path / "h.db", "--serial")
    assert code == 2 and "'last-week' is not a session date" in err


def test_simulate_command_writes_a_fleet(tmp_path, capsys):
    code, out, _ = run(capsys, "fleet", "simulate", "puma560", "-n", "4", "--out-dir",
                       tmp_path / "f", "--poses", "20", "--drifted", "1", "--broken", "1",
                       "--noise", "0.02mm", "--json", tmp_path / "s.json")
    assert code == 0
    doc = json.loads((tmp_path / "s.json").read_text())
    assert sum(1 for r in doc["robots"] if r["drift"]) == 1
    assert len(load_fleet(tmp_path / "f")) == 8
    truth = json.loads((tmp_path / "f" / "truth.json").read_text())
    assert truth["noise_m"] == pytest.approx(2e-5)
    code, _, err = run(capsys, "fleet", "simulate", "puma560", "--out-dir", tmp_path / "g",
                       "--noise", "0.02")
    assert code == 2 and "--noise" in err and "needs a unit" in err


def test_the_command_line_starts_without_dask_or_sqlalchemy():
    code = ("import sys, kincal.cli; heavy = [m for m in ('dask', 'distributed', "
            "'sqlalchemy') if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_only_the_fleet_package_imports_dask_or_sqlalchemy_at_module_level():
    src = Path(kincal.__file__).parent
    bad = []
    for path in src.rglob("*.py"):
        if "fleet" in path.relative_to(src).parts[:1]:
            continue
        for node in ast.parse(path.read_text()).body:       # module level only
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            if any(n.split(".")[0] in ("dask", "distributed", "sqlalchemy") for n in names):
                bad.append(str(path.relative_to(src)))
    assert not bad, bad


def test_calibrate_runs_its_cross_validation_folds_on_a_local_cluster(small, tmp_path):
    """`kincal calibrate --cross-validate K --workers 2`: the fold fits run on a real
    LocalCluster and give exactly the in-process numbers."""
    r = small.robots[0]
    data = small.root / r["serial"] / r["dates"][0] / "tracker.csv"
    docs = []
    for extra in ([], ["--workers", "2"]):
        out = tmp_path / f"r{len(docs)}.json"
        assert invoke("calibrate", "puma560", "--data", data, "--cross-validate", "4",
                      "--json", out, *extra) == 0
        docs.append(json.loads(out.read_text())["metrics"]["cross_validation"])
    assert docs[0] == docs[1]
